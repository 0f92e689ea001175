"""The configured GigE Vision camera everywhere (issue 40): ``commission`` (``--status`` and a
capture) and the console open ``camera.driver: gige`` through the factory ``campaign run`` uses,
against Aravis's fake camera (``arv-fake-gv-camera-0.8``, fixture ``fake_gv``), on a field whose
drives are the simulated plant's firmware on a pty and whose lamp panel is its Modbus TCP panel.
No ``--camera-manifest``, no ``--simulate``."""

from __future__ import annotations

import copy
import json
import urllib.request

import pytest
import yaml

from simplant.plant import SimulatedPlant, load_config_data
from tests.calibration.conftest import REPO
from tests.conftest import run_cli, scaled_s
from tests.console.conftest import ConsoleProcess
from tests.devices.conftest import FAKE_SKEW_MS, make_camera_config

# The fake GigE camera owns 127.0.0.1:3956: its tests run on one worker, one after the other,
# instead of one worker waiting on the port's lock for the other's (fake_gv).
pytestmark = pytest.mark.xdist_group("gige")

HID = "H02"  # serial bus 1 of the demo plant


@pytest.fixture
def gige_field(fake_gv, tmp_path):
    """The simulated plant's drives and lamp panel, and a configuration naming them with the
    fake GigE camera as its only camera (one target; no registration: the fake shows no lamps)."""
    with SimulatedPlant(load_config_data(REPO / "configs" / "demo.yaml"), tmp_path / "plant",
                        heliostat_ids=[HID], seed=3) as plant:
        plant.start()
        data = copy.deepcopy(plant.data)
        cam = make_camera_config(fake_gv.device_id, max_skew_ms=FAKE_SKEW_MS)
        data["camera"] = {**cam.model_dump(mode="json", exclude_none=True),
                          "sensors": data["camera"]["sensors"]}
        for t in data["targets"]:
            t.pop("camera", None)
        data["calibration"]["targets"] = [data["calibration"]["target"]]
        data["lamps"]["channels"] = {k: v for k, v in data["lamps"]["channels"].items()
                                     if not k.startswith("fiducials:")}
        path = tmp_path / "gige.yaml"
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        yield plant, path, [s["exposure_s"] for s in data["camera"]["sensors"]]


def test_commission_status_and_capture_use_the_configured_gige_camera(gige_field, tmp_path):
    plant, path, exposures = gige_field
    code, out, err = run_cli(["commission", "--config", str(path), "--heliostat", HID, "--status", "--json"])
    assert code == 0, err
    st = plant.hidden[HID].controller.status()
    assert json.loads(out)["steps"]["status"]["az_steps"] == st["az_steps"]
    png = tmp_path / "look.png"
    code, out, err = run_cli(["commission", "--config", str(path), "--heliostat", HID, "--capture", str(png),
                              "--json"])
    assert code == 0, err
    cap = json.loads(out)["steps"]["capture"]
    assert cap["exposures"] == pytest.approx(exposures)  # the GigE imagers' pair, as configured
    assert png.is_file()


def test_the_console_drives_and_captures_through_the_configured_gige_camera(gige_field, tmp_path):
    plant, path, exposures = gige_field
    proc = ConsoleProcess(["--config", str(path), "--db", str(tmp_path / "c.db"), "--port", "0"])
    try:
        with urllib.request.urlopen(f"{proc.url}/api/plant", timeout=scaled_s(10)) as r:
            assert [h["id"] for h in json.load(r)["heliostats"]] == [h.id for h in plant.cfg.heliostats]
        req = urllib.request.Request(f"{proc.url}/api/heliostats/{HID}/capture", data=b"{}", method="POST",
                                     headers={"Content-Type": "application/json"})
        with urllib.request.urlopen(req, timeout=scaled_s(30)) as r:
            cap = json.load(r)
        assert cap["ok"] and cap["result"]["exposures"] == pytest.approx(exposures)
    finally:
        code = proc.stop()
    assert code in (0, 130), "".join(proc.stderr)  # Ctrl-C ends it
