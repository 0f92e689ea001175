"""Simulated and file cameras, and auto-exposure."""

import cv2
import numpy as np
import pytest

from controller.calibration.cycle.exposure import auto_expose
from controller.config import Camera
from controller.devices.camera import CameraError
from controller.devices.file_camera import FileCamera
from controller.errors import InputError
from controller.imaging.autoexposure import next_exposures
from simplant.devices.camera import SimulatedCamera


def camera_cfg(t=(0.010, 0.020), gains=(1.0, 1.03)):
    return Camera(sensors=({"name": "ccd1", "exposure_s": t[0], "gain": gains[0]},
                           {"name": "ccd2", "exposure_s": t[1], "gain": gains[1]}),
                  width_px=64, height_px=48)


def test_simulated_pair_same_instant_gain_mismatch():
    scene = np.full((48, 64), 4000.0)
    cam = SimulatedCamera(camera_cfg(), lambda: scene, seed=1, clock=lambda: 123.0, knees=(0.0, 0.0))
    pair = cam.capture()
    assert pair.low.shape == (48, 64) and pair.low.dtype == np.uint8
    assert pair.exposures == (0.010, 0.020) and pair.timestamp == 123.0
    # linear sensors: LOW 40 counts, HIGH 80 * 1.03 = 82.4 counts above the offset
    assert pair.low.mean() - 8 == pytest.approx(40.0, abs=0.3)
    assert pair.high.mean() - 8 == pytest.approx(82.4, abs=0.3)
    crf = cam.true_crf()
    assert crf.inverse(1)[90] == pytest.approx(82.0 / 1.03)


def test_simulated_failure_injection_and_bad_scene():
    cam = SimulatedCamera(camera_cfg(), lambda: np.zeros((4, 4)))
    cam.inject_failure()
    with pytest.raises(CameraError):
        cam.capture()
    cam.capture()
    bad = SimulatedCamera(camera_cfg(), lambda: np.full((4, 4), np.nan))
    with pytest.raises(CameraError, match="NaN"):
        bad.capture()
    with pytest.raises(CameraError):
        cam.set_exposures(0.02, 0.01)


def test_file_camera_replays_manifest(tmp_path):
    for i in range(2):
        cv2.imwrite(str(tmp_path / f"l{i}.png"), np.full((5, 6), 10 + i, np.uint8))
        cv2.imwrite(str(tmp_path / f"h{i}.png"), np.full((5, 6), 20 + i, np.uint8))
    (tmp_path / "m.yaml").write_text(
        "pairs:\n"
        "  - {low: l0.png, high: h0.png, exposures: [0.01, 0.02], timestamp: 5.0}\n"
        "  - {low: l1.png, high: h1.png, exposures: [0.005, 0.04], metadata: {heliostat: H01}}\n")
    cam = FileCamera(tmp_path / "m.yaml")
    a, b = cam.capture(), cam.capture()
    assert a.low[0, 0] == 10 and a.high[0, 0] == 20 and a.timestamp == 5.0
    assert b.exposures == (0.005, 0.04) and b.metadata["heliostat"] == "H01" and b.timestamp == 1.0
    with pytest.raises(CameraError, match="replayed"):
        cam.capture()
    looped = FileCamera(tmp_path / "m.yaml", loop=True)
    for _ in range(3):
        looped.capture()


@pytest.mark.parametrize("text, msg", [
    ("pairs: []", "pairs: required"),
    ("pairs:\n  - {low: a.png, high: b.png}", r"pairs\[0\].exposures: required"),
    ("pairs:\n  - {low: a.png, high: b.png, exposures: [0.02, 0.01]}", "t_low <= t_high"),
    ("pairs:\n  - {low: nope.png, high: b.png, exposures: [0.01, 0.02]}", "not found"),
])
def test_file_camera_bad_manifest(tmp_path, text, msg):
    (tmp_path / "m.yaml").write_text(text)
    with pytest.raises(InputError, match=msg):
        FileCamera(tmp_path / "m.yaml")


def test_next_exposures_rule():
    low_sat = np.array([[255, 100]], np.uint8)
    assert next_exposures(low_sat, low_sat, (0.01, 0.02)).action == "shorter"
    dim = np.array([[30, 20]], np.uint8)
    step = next_exposures(dim, dim, (0.01, 0.02))
    assert step.action == "longer" and step.exposures == (0.02, 0.04)
    good = next_exposures(np.array([[150]], np.uint8), np.array([[255]], np.uint8), (0.01, 0.02))
    assert good.action == "ok"


def test_auto_expose_converges_on_a_spot():
    y, x = np.mgrid[0:48, 0:64]
    scene = 40000.0 * np.exp(-((x - 32) ** 2 + (y - 24) ** 2) / 50.0)
    cam = SimulatedCamera(camera_cfg((0.08, 0.16)), lambda: scene, seed=3)  # far too long at start
    res = auto_expose(cam)
    assert res.converged
    pair = cam.capture()
    assert (pair.low == 255).sum() == 0           # LOW not saturated in the core
    assert pair.high.max() - 8 >= 0.5 * 247        # HIGH has useful signal
    assert res.exposures[1] / res.exposures[0] == pytest.approx(2.0)
