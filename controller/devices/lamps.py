"""The plant's fiducial-lamp controller, reached through a command the plant supplies.

Camera registration (docs/camera.md, "Registration") needs the target's fiducial lamps off
for one capture and on for the next. Plants switch such lamps through their own controller
(a PLC output, a relay box, a script); heliocal runs the configured command
``camera.registration.lamp_command`` with ``on`` or ``off`` appended and waits for it. The
command must exit 0 once the lamps are in that state; anything else stops the registration
with a clear error before the campaign opens, so no measurement is taken on a wrong frame.
"""

from __future__ import annotations

import subprocess

from controller.errors import DeviceError

LAMP_COMMAND_TIMEOUT_S = 30.0


class LampCommandError(DeviceError):
    """The fiducial-lamp command failed, timed out or could not be started."""


def switch_lamps(argv: tuple[str, ...], on: bool, timeout_s: float = LAMP_COMMAND_TIMEOUT_S) -> None:
    """Run ``argv + [on|off]`` (no shell) and wait up to ``timeout_s`` s for exit status 0."""
    state = "on" if on else "off"
    cmd = [*argv, state]
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)
    except FileNotFoundError:
        raise LampCommandError(f"camera.registration.lamp_command: {argv[0]!r} not found") from None
    except PermissionError:
        raise LampCommandError(f"camera.registration.lamp_command: {argv[0]!r} is not executable") from None
    except subprocess.TimeoutExpired:
        raise LampCommandError(f"camera.registration.lamp_command: switching the fiducial lamps {state} "
                               f"did not finish within {timeout_s:g} s") from None
    if r.returncode != 0:
        said = (r.stderr or r.stdout).strip().splitlines()
        raise LampCommandError(f"camera.registration.lamp_command: switching the fiducial lamps {state} "
                               f"exited {r.returncode}" + (f": {said[-1]}" if said else ""))
