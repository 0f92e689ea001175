"""The camera.gige configuration section, the camera factory and ``heliocal capture``."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from controller.cli import main
from controller.commands.common import PACKAGED_CONFIG
from controller.config import load_config
from controller.devices.factory import open_camera
from controller.devices.gige import GigeCamera
from controller.errors import ConfigError, InputError
from tests.devices.conftest import FAKE_SKEW_MS

# The fake GigE camera owns 127.0.0.1:3956: its tests run on one worker, one after the other,
# instead of one worker waiting on the port's lock for the other's (fake_gv).
pytestmark = pytest.mark.xdist_group("gige")


def _plant(tmp_path: Path, camera: dict) -> Path:
    """The packaged demo plant with its camera section updated by ``camera``."""
    doc = yaml.safe_load(Path(PACKAGED_CONFIG).read_text())
    doc["camera"].update(camera)
    path = tmp_path / "plant.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def _gige(low: str = "Aravis-Fake-A", high: str = "Fake_1", **kw) -> dict:
    return {"driver": "gige", "gige": {"low": low, "high": high, **kw}}


@pytest.mark.parametrize(("camera", "message"), [
    ({"gige": {"low": "A", "high": "B", "trigger": "Line"}},
     "camera.gige.trigger: 'Line': must be software, free or LineN"),
    ({"gige": {"low": "A", "high": "B", "pixel_format": "RGB8"}},
     "camera.gige.pixel_format: Input should be 'Mono8', 'Mono12' or 'Mono16'"),
    ({"gige": {"low": "A", "high": "A"}}, "camera.gige: low and high name the same imager 'A'"),
    ({"gige": {"low": "A", "high": "B", "max_skew_ms": 0}},
     "camera.gige.max_skew_ms: Input should be greater"),
    ({"gige": {"low": "A", "high": "B", "buffer": 4}},
     "camera.gige.buffer: unknown key (did you mean 'buffers'?)"),
    ({"driver": "gige"}, "camera: gige: required key is missing (driver is gige)"),
    ({"driver": "file"}, "camera: manifest: required key is missing (driver is file)"),
    ({"gige": {"low": "A", "high": "B", "pixel_format": "Mono16"}},
     "gige.pixel_format: Mono16 delivers 16-bit pixels but bit_depth is 8"),
    ({"bit_depth": 10, "gige": {"low": "A", "high": "B"}}, "gige.pixel_format: required for bit_depth 10"),
])
def test_bad_gige_sections_name_file_key_and_rule(tmp_path, camera, message):
    path = _plant(tmp_path, camera)
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert str(err.value).startswith(f"{path}: ")
    assert message in str(err.value)


def test_defaults_and_pixel_format_from_bit_depth(tmp_path):
    cam = load_config(_plant(tmp_path, {**_gige(), "bit_depth": 16})).camera
    assert cam.gige_pixel_format() == "Mono16"
    g = cam.gige
    assert (g.trigger, g.max_skew_ms, g.timeout_ms, g.buffers) == ("software", 1.0, 2000, 4)
    assert g.roi_offset_px == (0, 0)


def test_factory_without_a_camera_says_what_to_set(tmp_path):
    cfg = load_config(_plant(tmp_path, {}))
    with pytest.raises(InputError, match="sets no camera.driver"):
        open_camera(cfg.camera)


def test_factory_and_capture_command_use_the_gige_camera(fake_gv, tmp_path, capsys):
    path = _plant(tmp_path, {**_gige(fake_gv.device_id, max_skew_ms=FAKE_SKEW_MS), "bit_depth": 16,
                             "width_px": 64, "height_px": 48})
    camera = open_camera(load_config(path).camera)
    try:
        assert isinstance(camera, GigeCamera)
    finally:
        camera.close()
    out = tmp_path / "pair"
    assert main(["capture", "--camera", "gige", "--config", str(path), "--out", str(out), "--json"]) == 0
    meta = json.loads(capsys.readouterr().out)
    assert sorted(p.name for p in out.iterdir()) == ["high.png", "low.png", "metadata.json"]
    assert json.loads((out / "metadata.json").read_text()) == meta
    low = cv2.imread(str(out / "low.png"), cv2.IMREAD_UNCHANGED)
    assert low.dtype == np.uint16 and low.shape == (48, 64) and low.max() > 255
    assert meta["devices"] == [fake_gv.device_id, "Fake_1"]
    assert meta["exposures_s"] == pytest.approx([0.010, 0.020])
    assert meta["pixel_format"] == "Mono16" and meta["roi"] == [0, 0, 64, 48]
    assert meta["skew_ms"] == pytest.approx(abs(meta["timestamps_ns"][0] - meta["timestamps_ns"][1]) / 1e6)


def test_capture_command_refuses_before_writing(tmp_path, capsys):
    path = _plant(tmp_path, {})
    out = tmp_path / "pair"
    assert main(["capture", "--camera", "gige", "--config", str(path), "--out", str(out)]) == 2
    assert "camera.gige: required key is missing for --camera gige" in capsys.readouterr().err
    assert main(["capture", "--camera", "file", "--config", str(path), "--out", str(out)]) == 2
    assert "--manifest FILE is required" in capsys.readouterr().err
    assert not out.exists()


def test_campaign_run_opens_the_configured_gige_camera(tmp_path, capsys):
    """No --camera-manifest: campaign run opens camera.driver's camera (here: not there)."""
    path = _plant(tmp_path, {**_gige("Aravis-Fake-NOSUCH"), "bit_depth": 16})
    assert main(["campaign", "run", "--config", str(path), "--db", str(tmp_path / "c.db"), "--json"]) == 1
    assert json.loads(capsys.readouterr().out)["error"].startswith("GigE camera: ")


def test_capture_without_camera_opens_the_configured_file_driver(tmp_path, capsys):
    """``camera.driver: file``: every command's camera is the recorded pairs of camera.manifest
    (the same factory); ``capture`` without ``--camera`` takes the configured driver."""
    frames = tmp_path / "frames"
    frames.mkdir()
    for name, value in (("low", 40), ("high", 90)):
        assert cv2.imwrite(str(frames / f"{name}.png"), np.full((48, 64), value, np.uint8))
    manifest = tmp_path / "pairs.yaml"
    manifest.write_text(yaml.safe_dump({"pairs": [{"low": "frames/low.png", "high": "frames/high.png",
                                                   "exposures": [0.003, 0.006]}]}))
    path = _plant(tmp_path, {"driver": "file", "manifest": str(manifest), "width_px": 64, "height_px": 48})
    out = tmp_path / "pair"
    assert main(["capture", "--config", str(path), "--out", str(out), "--json"]) == 0
    meta = json.loads(capsys.readouterr().out)
    assert meta["camera"] == "file" and meta["exposures_s"] == [0.003, 0.006]
    assert cv2.imread(str(out / "high.png"), cv2.IMREAD_UNCHANGED).max() == 90
    path = _plant(tmp_path, {})
    assert main(["capture", "--config", str(path), "--out", str(out)]) == 2
    assert "sets no camera.driver" in capsys.readouterr().err
