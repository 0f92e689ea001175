"""The command lamp driver (``lamps.driver: command``) with a small switch program in its own
process, which keeps its lamps in a state file: the driver's view is checked against that file."""

from __future__ import annotations

import json
import sys
import time

import pytest

from controller.config import CommandLamps
from controller.devices.lamp_command import OUTPUT_LIMIT_BYTES, LampCommandError
from controller.devices.lamp_drivers import open_lamp_panel
from controller.devices.lamp_panel import (
    LampNotConfirmed,
    light_only,
    lights_out,
    set_and_confirm,
)
from controller.devices.plant_time import PlantTime
from tests.conftest import scaled_s

# argv: STATE VERB CHANNEL. "stuck" switches but never lights; "broken" fails every request.
SWITCH = """\
import json, pathlib, sys
state_file, verb, channel = pathlib.Path(sys.argv[1]), sys.argv[2], sys.argv[3]
state = json.loads(state_file.read_text()) if state_file.exists() else {}
if channel == "broken":
    print("relay 4 does not answer", file=sys.stderr)
    sys.exit(3)
if verb == "status":
    sys.exit(0 if state.get(channel) else 1)
state[channel] = verb == "on" and channel != "stuck"
state_file.write_text(json.dumps(state))
"""


@pytest.fixture
def lamps(tmp_path):
    script, state = tmp_path / "switch.py", tmp_path / "state.json"
    script.write_text(SWITCH)
    cfg = CommandLamps(driver="command", command=(sys.executable, str(script), str(state)),
                       channels={"lamp-west": 0, "lamp-east": 1, "stuck": 2, "broken": 3},
                       timeout_s=scaled_s(20))
    return cfg, state


def _time() -> PlantTime:
    return PlantTime(poll_s=scaled_s(0.02))


def test_the_command_switches_confirms_and_reports(lamps):
    cfg, state = lamps
    cfg = cfg.model_copy(update={"channels": {"lamp-west": 0, "lamp-east": 1, "stuck": 2}})
    with open_lamp_panel(cfg) as panel:
        set_and_confirm(panel, "lamp-east", True, time=_time(), timeout_s=scaled_s(5))
        light_only(panel, "lamp-west", time=_time(), timeout_s=scaled_s(5))
        assert json.loads(state.read_text()) == {"lamp-east": False, "stuck": False, "lamp-west": True}
        assert [s.to_json() for s in panel.states()] == [
            {"channel": "lamp-west", "commanded": True, "lit": True},
            {"channel": "lamp-east", "commanded": False, "lit": False},
            {"channel": "stuck", "commanded": False, "lit": False}]
        lights_out(panel, time=_time(), timeout_s=scaled_s(5))
        assert not any(json.loads(state.read_text()).values())


def test_a_lamp_the_program_cannot_light_does_not_confirm(lamps):
    cfg, _ = lamps
    with open_lamp_panel(cfg) as panel, pytest.raises(
            LampNotConfirmed, match=r"^lamp stuck did not confirm lit within"):
        set_and_confirm(panel, "stuck", True, time=_time(), timeout_s=scaled_s(0.3))


def test_a_failing_program_is_one_line_with_its_reason(lamps):
    cfg, _ = lamps
    with open_lamp_panel(cfg) as panel:
        with pytest.raises(LampCommandError, match=(
                r"^lamps.command: switching lamp broken on exited 3: relay 4 does not answer$")):
            panel.switch("broken", True)
        with pytest.raises(LampCommandError, match=(
                r"^lamps.command: asking the status of lamp broken exited 3: relay 4 does not answer$")):
            panel.confirmed("broken")
        with pytest.raises(LampCommandError, match="switching lamp broken off exited 3"):
            lights_out(panel, time=_time(), timeout_s=scaled_s(1))
    missing = cfg.model_copy(update={"command": ("/nonexistent/lamp-switch",)})
    with open_lamp_panel(missing) as panel, pytest.raises(
            LampCommandError, match="lamps.command: '/nonexistent/lamp-switch' not found"):
        panel.switch("lamp-west", True)


def _panel(tmp_path, program: str | list[str], *, timeout_s: float = 5.0, mode: int = 0o755):
    """A command panel running ``program`` (a shell script's text, or an argv as is)."""
    if isinstance(program, str):
        script = tmp_path / "switch"
        script.write_text(program)
        script.chmod(mode)
        program = [str(script)]
    cfg = CommandLamps(driver="command", command=tuple(program), channels={"lamp-west": 0},
                       timeout_s=scaled_s(timeout_s))
    return open_lamp_panel(cfg)


def _gone(pid: int) -> bool:
    """Whether process ``pid`` is gone (or a zombie waiting for its reaper), within a bound."""
    deadline = time.monotonic() + scaled_s(5)
    while time.monotonic() < deadline:
        try:
            with open(f"/proc/{pid}/stat") as f:
                if f.read().rsplit(")", 1)[1].split()[0] == "Z":
                    return True
        except FileNotFoundError:
            return True
        time.sleep(0.01)
    return False


@pytest.mark.parametrize("content, mode, said", [
    (b"echo no shebang line\n", 0o755, "cannot be executed: not a program for this system"),
    (b"MZ\x90\x00" + bytes(60), 0o755, "cannot be executed: not a program for this system"),
    (b"\x7fELF\x02\x01\x01" + bytes(57), 0o755, "cannot be executed: not a program for this system"),
    (b"#!/bin/sh\nexit 0\n", 0o644, "is not executable"),
    (b"#!/nonexistent/interpreter\n", 0o755, "not found (or the interpreter its #! line names)"),
])
def test_a_program_the_system_cannot_run_is_named_in_one_line(tmp_path, content, mode, said):
    program = tmp_path / "lamp-switch"
    program.write_bytes(content)
    program.chmod(mode)
    with _panel(tmp_path, [str(program)]) as panel, pytest.raises(LampCommandError) as e:
        panel.switch("lamp-west", True)
    assert str(e.value).startswith(f"lamps.command: {str(program)!r} {said}")
    assert "\n" not in str(e.value)
    folder = _panel(tmp_path, [str(tmp_path)])
    with folder as panel, pytest.raises(LampCommandError, match="is not executable"):
        panel.confirmed("lamp-west")


def test_output_that_is_not_utf8_is_decoded_leniently(tmp_path):
    failing = "#!/bin/sh\nprintf 'relay \\377\\376 4 offline\\n' >&2\nexit 3\n"
    with _panel(tmp_path, failing) as panel, pytest.raises(LampCommandError) as e:
        panel.switch("lamp-west", True)
    assert str(e.value) == "lamps.command: switching lamp lamp-west on exited 3: relay \ufffd\ufffd 4 offline"
    lit = "#!/bin/sh\nprintf '\\377\\000\\033[31m lit\\n'\nexit 0\n"
    with _panel(tmp_path, lit) as panel:
        assert panel.confirmed("lamp-west") is True


def test_a_program_that_floods_its_output_is_stopped_at_the_limit(tmp_path):
    flood = [sys.executable, "-c", "import sys\nwhile True: sys.stdout.write('x' * 65536)"]
    t0 = time.monotonic()
    with _panel(tmp_path, flood, timeout_s=60) as panel, pytest.raises(LampCommandError) as e:
        panel.switch("lamp-west", True)
    assert str(e.value) == (f"lamps.command: switching lamp lamp-west on: the program printed more than "
                            f"{OUTPUT_LIMIT_BYTES} bytes on stdout")
    assert time.monotonic() - t0 < scaled_s(10)  # stopped at the limit, not at the 60 s timeout


def test_a_child_left_holding_the_output_neither_delays_nor_survives(tmp_path):
    pid_file = tmp_path / "child.pid"
    leaves_child = f"#!/bin/sh\nsleep 300 &\necho $! > {pid_file}\nexit 0\n"
    t0 = time.monotonic()
    with _panel(tmp_path, leaves_child, timeout_s=60) as panel:
        panel.switch("lamp-west", True)
    assert time.monotonic() - t0 < scaled_s(10)  # not the child's 300 s, nor the 60 s timeout
    assert _gone(int(pid_file.read_text()))


def test_on_timeout_the_whole_group_is_killed(tmp_path):
    pid_file = tmp_path / "child.pid"
    # The child ignores SIGTERM and SIGINT; the program itself never ends.
    hangs = f"#!/bin/sh\n(trap '' TERM INT; sleep 300) &\necho $! > {pid_file}\nsleep 300\n"
    t0 = time.monotonic()
    with _panel(tmp_path, hangs, timeout_s=0.5) as panel, pytest.raises(LampCommandError) as e:
        panel.switch("lamp-west", False)
    assert str(e.value) == ("lamps.command: switching lamp lamp-west off did not finish within "
                            f"{scaled_s(0.5):g} s")
    assert time.monotonic() - t0 < scaled_s(5)
    assert _gone(int(pid_file.read_text()))


def test_a_child_that_left_the_group_but_holds_the_output_is_killed_too(tmp_path):
    pid_file = tmp_path / "child.pid"
    # setsid: the child leads a session of its own, out of the program's process group.
    escapes = (f"#!/bin/sh\nsetsid sh -c 'echo $$ > {pid_file}; exec sleep 300' &\n"
               f"while [ ! -s {pid_file} ]; do :; done\nexit 0\n")
    t0 = time.monotonic()
    with _panel(tmp_path, escapes, timeout_s=60) as panel:
        panel.switch("lamp-west", True)
    assert time.monotonic() - t0 < scaled_s(10)
    assert _gone(int(pid_file.read_text()))
