"""Lamps switched by the plant's own program (``lamps.driver: command``, docs/lamps.md).

The controller runs the configured argv (no shell) with two arguments appended:

* ``on CHANNEL`` / ``off CHANNEL``: exit 0 once the lamp is in that state (switched *and*
  confirmed by the plant's controller); anything else is a :class:`LampCommandError`;
* ``status CHANNEL``: exit 0 when the lamp is lit, 1 when it is dark; anything else is an error.

``camera.registration.lamp_command`` (docs/camera.md, "Registration") is the same driver with
one channel, the target's fiducial lamps, and no channel argument: ``argv + [on|off]``, and no
``status`` verb — a switch that exited 0 is its confirmation (:func:`fiducial_command_panel`).
"""

from __future__ import annotations

import subprocess

from controller.devices.lamp_panel import LampError, LampPanel, LampState

LAMP_COMMAND_TIMEOUT_S = 30.0  # camera.registration.lamp_command
_FIDUCIALS = "fiducials"


class LampCommandError(LampError):
    """The switch program failed, timed out or could not be started."""


class CommandLampPanel(LampPanel):
    """``argv`` run per request; ``key`` is the configuration key messages name.
    ``with_status=False``: the program knows no ``status`` verb and takes no channel argument
    (the registration's ``lamp_command``)."""

    def __init__(self, argv: tuple[str, ...], channels: tuple[str, ...], timeout_s: float, *,
                 key: str = "lamps.command", with_status: bool = True) -> None:
        self.argv = tuple(argv)
        self.channels = tuple(channels)
        self.timeout_s = timeout_s
        self.name = key
        self.with_status = with_status
        self._commanded: dict[str, bool] = {}

    def _what(self, channel: str) -> str:
        return f"lamp {channel}" if self.with_status else "the fiducial lamps"

    def _run(self, verb: str, channel: str, doing: str) -> tuple[int, list[str]]:
        """(exit status, the lines it printed on stderr, else stdout)."""
        cmd = [*self.argv, verb, channel] if self.with_status else [*self.argv, verb]
        try:
            r = subprocess.run(cmd, capture_output=True, text=True, timeout=self.timeout_s, check=False)
        except FileNotFoundError:
            raise LampCommandError(f"{self.name}: {self.argv[0]!r} not found") from None
        except PermissionError:
            raise LampCommandError(f"{self.name}: {self.argv[0]!r} is not executable") from None
        except subprocess.TimeoutExpired:
            raise LampCommandError(f"{self.name}: {doing} did not finish within "
                                   f"{self.timeout_s:g} s") from None
        return r.returncode, (r.stderr or r.stdout).strip().splitlines()

    def _failed(self, doing: str, code: int, said: list[str]) -> LampCommandError:
        return LampCommandError(f"{self.name}: {doing} exited {code}" + (f": {said[-1]}" if said else ""))

    def switch(self, channel: str, on: bool) -> None:
        state = "on" if on else "off"
        doing = f"switching {self._what(self.check_channel(channel))} {state}"
        code, said = self._run(state, channel, doing)
        if code != 0:
            self._commanded.pop(channel, None)  # unknown now
            raise self._failed(doing, code, said)
        self._commanded[channel] = bool(on)

    def confirmed(self, channel: str) -> bool:
        self.check_channel(channel)
        if not self.with_status:
            return self._commanded.get(channel, False)  # exit 0 of the switch confirmed it
        doing = f"asking the status of {self._what(channel)}"
        code, said = self._run("status", channel, doing)
        if code not in (0, 1):
            raise self._failed(doing, code, said)
        return code == 0

    def states(self) -> list[LampState]:
        return [LampState(c, self._commanded.get(c), self.confirmed(c)) for c in self.channels]

    def close(self) -> None:
        """Nothing is held open between runs."""


def fiducial_command_panel(argv: tuple[str, ...]) -> tuple[CommandLampPanel, str]:
    """``camera.registration.lamp_command`` as a panel, and its one channel's name."""
    return (CommandLampPanel(argv, (_FIDUCIALS,), LAMP_COMMAND_TIMEOUT_S,
                             key="camera.registration.lamp_command", with_status=False), _FIDUCIALS)
