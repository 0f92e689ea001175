"""The plant's fiducial-lamp controller as a command (camera.registration.lamp_command).

The command runs in its own process and is the only thing that switches the simulated
camera's fiducial lamps here (through a state file the camera reads at each capture), so a
registration that succeeds proves the command was run with 'off', then 'on', then 'off'."""

from __future__ import annotations

import sys

import pytest

from controller.calibration.cycle.beam_chain import BeamChain
from controller.calibration.cycle.registration_step import register_camera
from controller.config import parse_config
from controller.devices.lamp_command import LampCommandError
from controller.errors import ConfigError
from simplant.devices.plant_camera import PlantCamera
from simplant.plant import SimulatedPlant, load_config_data
from tests.calibration.conftest import REPO

SWITCH = "import pathlib, sys\nwith open(sys.argv[1], 'a') as f:\n    f.write(sys.argv[2] + '\\n')\n"


class _LampWiredCamera:
    """The plant camera whose fiducials follow the last state the lamp command wrote."""

    def __init__(self, cam: PlantCamera, state) -> None:
        self.cam, self.state = cam, state

    def capture(self):
        lines = self.state.read_text().split() if self.state.exists() else []
        self.cam.fiducials_lit = bool(lines) and lines[-1] == "on"
        return self.cam.capture()


def _plant(tmp_path, command):
    data = load_config_data(REPO / "configs" / "demo.yaml")
    data["camera"]["registration"]["lamp_command"] = command
    return SimulatedPlant(data, tmp_path / "plant", heliostat_ids=["H01"], seed=3)


def _never(on: bool) -> None:
    raise AssertionError("the caller's lamp hook must not be used when lamp_command is configured")


def test_lamp_command_switches_the_fiducials_for_registration(tmp_path):
    state, script = tmp_path / "lamps.log", tmp_path / "switch.py"
    script.write_text(SWITCH)
    plant = _plant(tmp_path, [sys.executable, str(script), str(state)])
    cam = PlantCamera(plant, plant.cfg, seed=3, perspective=True)
    reg = register_camera(plant.cfg, _LampWiredCamera(cam, state), _never, BeamChain(plant.cfg).frame)
    assert state.read_text().split() == ["off", "on", "off"]  # and left off
    assert reg.found == 9 and reg.low.rms_px < 0.1 and reg.high.rms_px < 0.1


@pytest.mark.parametrize("command, said", [
    ([sys.executable, "-c", "import sys; print('relay box offline', file=sys.stderr); sys.exit(3)"],
     "switching the fiducial lamps off exited 3: relay box offline"),
    (["/nonexistent/lamp-switch"], "'/nonexistent/lamp-switch' not found"),
])
def test_a_failing_lamp_command_stops_the_registration_with_its_reason(tmp_path, command, said):
    plant = _plant(tmp_path, command)
    cam = PlantCamera(plant, plant.cfg, seed=3, perspective=True)
    with pytest.raises(LampCommandError, match="camera.registration.lamp_command") as e:
        register_camera(plant.cfg, cam, _never, BeamChain(plant.cfg).frame)
    assert said in str(e.value)


def test_an_empty_lamp_command_is_refused_naming_the_key():
    data = load_config_data(REPO / "configs" / "demo.yaml")
    data["camera"]["registration"]["lamp_command"] = []
    with pytest.raises(ConfigError, match=r"camera\.registration\.lamp_command"):
        parse_config(data, "plant.yaml")
