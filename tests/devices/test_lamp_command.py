"""The command lamp driver (``lamps.driver: command``) with a small switch program in its own
process, which keeps its lamps in a state file: the driver's view is checked against that file."""

from __future__ import annotations

import json
import sys

import pytest

from controller.config import CommandLamps
from controller.devices.lamp_command import LampCommandError
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
