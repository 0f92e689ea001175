"""Fiducial detection, the look-at pose and the saturation-safe rectification
(controller.imaging.fiducials), and the numpy projection against OpenCV's."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from controller.errors import ConfigError, InputError
from controller.imaging.fiducials import detect_fiducials, look_at_pose, rectify_sensor
from controller.imaging.registration import CameraModel, remap

REPO_DEMO = "configs/demo.yaml"


def test_look_at_pose_puts_the_target_on_the_optical_axis_with_rows_running_down():
    c, at = np.array([4.0, 90.0, 3.0]), np.array([0.0, 0.0, 30.0])
    rvec, tvec = look_at_pose(c, at)
    k = np.array([[1000.0, 0, 500.0], [0, 1000.0, 400.0], [0, 0, 1]])
    m = CameraModel(k, np.zeros(5), rvec, tvec, (1000, 800))
    np.testing.assert_allclose(m.center_enu, c, atol=1e-9)
    np.testing.assert_allclose(m.project(at[None]), [[500.0, 400.0]], atol=1e-9)
    up, west = m.project(np.array([[0.0, 0.0, 31.0], [-1.0, 0.0, 30.0]]))
    assert up[1] < 400.0 and abs(up[0] - 500.0) < 1.0  # higher on the target: smaller row
    assert west[0] > 500.0  # looking south, west is on the right
    # a roll turns the image about the line of sight, clockwise on screen for a positive angle
    rolled = CameraModel(k, np.zeros(5), *look_at_pose(c, at, 0.01), (1000, 800))
    rolled = rolled.project(at[None] + [[-1.0, 0.0, 0.0]])
    assert rolled[0, 1] < west[1]
    with pytest.raises(InputError, match="straight up"):
        look_at_pose([0, 0, 0], [0, 0, 10])


def test_numpy_projection_is_opencvs():
    rng = np.random.default_rng(1)
    m = CameraModel(np.array([[800.0, 0, 320.0], [0, 800.0, 240.0], [0, 0, 1]]),
                    np.array([-0.25, 0.1, 1e-3, -2e-3, 0.02]), np.array([0.1, -0.2, 0.05]),
                    np.array([0.3, -0.1, 5.0]), (640, 480))
    pts = rng.uniform(-2.0, 2.0, (200, 3))
    ref, _ = cv2.projectPoints(pts, m.rvec, m.tvec, m.K, m.dist)
    np.testing.assert_allclose(m.project(pts), ref.reshape(-1, 2), atol=1e-9)


def _blobs(shape, centres, sigma=2.0, peak=200.0, seed=0):
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    img = np.random.default_rng(seed).normal(0.0, 1.0, shape)
    for u, v in centres:
        img += peak * np.exp(-((xx - u) ** 2 + (yy - v) ** 2) / (2 * sigma**2))
    return img


def test_detect_fiducials_finds_each_blob_near_its_prediction_to_a_hundredth_of_a_pixel():
    true = np.array([[40.3, 30.7], [160.55, 35.2], [100.1, 120.9], [30.0, 140.45]])
    img = _blobs((170, 200), true)
    predicted = true + [[12.0, -9.0]] * 4  # the nominal pose is off by ~15 px
    found = detect_fiducials(img, predicted, 25.0)
    np.testing.assert_allclose(found, true, atol=0.02)
    # out of reach, too faint or off the image: NaN rows, the others still found
    far = detect_fiducials(img, predicted + [[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, -60.0]], 25.0)
    assert np.isnan(far[3]).all() and np.isfinite(far[:3]).all()
    faint = detect_fiducials(_blobs((170, 200), true, peak=5.0), predicted, 25.0)
    assert np.isnan(faint).all()
    assert np.isnan(detect_fiducials(img, [[-100.0, -100.0]], 25.0)).all()


def test_rectify_sensor_keeps_saturation_where_a_plain_bilinear_remap_mixes_it():
    img = np.full((20, 20), 100, np.uint8)
    img[8:12, 8:12] = 255
    shift = (np.tile(np.arange(20, dtype=np.float32) + 0.5, (20, 1)),
             np.tile(np.arange(20, dtype=np.float32)[:, None], (1, 20)))  # half a pixel right
    plain = remap(img, shift)
    kept = rectify_sensor(img, shift, 255)
    assert plain[9, 7] not in (100, 255)  # a mix: neither a measurement nor marked clipped
    assert kept[9, 7] == 255 and kept[9, 11] == 255 and kept[9, 13] == 100  # 12 may be marked too
    assert kept.dtype == np.uint8
    np.testing.assert_array_equal(rectify_sensor(np.full((20, 20), 7, np.uint8), shift, 255)[:, :19], 7)


def test_registration_config_is_validated(tmp_path):
    from controller.config import load_config

    data = yaml.safe_load(open(REPO_DEMO, encoding="utf-8"))
    ok = tmp_path / "ok.yaml"
    ok.write_text(yaml.safe_dump(data))
    reg = load_config(ok).camera.registration
    assert reg.focal_px > 0 and len(reg.fiducials_enu_m) >= 4
    cases = [
        (lambda d: d["camera"].pop("position_enu_m"), "registration: needs position_enu_m"),
        (lambda d: d["camera"]["registration"].update(fiducials_enu_m=[[0, 0, 30]] * 3), "fiducials_enu_m"),
        (lambda d: d["camera"]["registration"].update(focal_px=-1), "focal_px"),
        (lambda d: d["camera"]["registration"].update(max_rms_px=0), "max_rms_px"),
        (lambda d: d["camera"]["registration"].update(fiducials_enu_m=[[0, 0, 30]] * 4), "distinct"),
        (lambda d: d["camera"]["registration"].update(lens="tele"), "lens"),
    ]
    for edit, match in cases:
        d = yaml.safe_load(yaml.safe_dump(data))
        edit(d)
        p = tmp_path / "bad.yaml"
        p.write_text(yaml.safe_dump(d))
        with pytest.raises(ConfigError, match=match) as exc:
            load_config(p)
        assert "bad.yaml" in str(exc.value) and "camera" in str(exc.value)
