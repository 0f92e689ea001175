"""``heliocal flux --crf`` linearises a non-linear camera; a saturated receiver is refused
(exit 2, naming the count) unless ``--allow-saturated``; the JSON reports ``saturated_px``."""

from __future__ import annotations

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest

from controller.cli import main
from controller.imaging.crf import Crf
from controller.imaging.crf_io import save_crf
from simplant.devices.sensor import knee_response

DNI, RHO, T_SUN, T_EXP = 900.0, 0.85, 0.01, 1e-3


def _png(path, img) -> str:
    assert cv2.imwrite(str(path), img)
    return str(path)


def _flux(capsys, *argv):
    code = main(["flux", *argv, "--dni", str(DNI), "--reflectivity", str(RHO), "--json"])
    cap = capsys.readouterr()
    return code, json.loads(cap.out.strip().splitlines()[-1]), cap.err


@pytest.fixture(scope="module")
def knee_scene(tmp_path_factory, camera, beam):
    """Sun, receiver (100 m, normal view) and ambient PNGs from a camera with a compressive
    response, its CRF file, and the true beam power."""
    d = tmp_path_factory.mktemp("knee")
    cam = replace(camera, sensor=replace(camera.sensor, response=knee_response(1.5)))
    rng = np.random.default_rng(15)
    field, power = beam(peak_w_m2=500e3)
    rate = cam.target_rate(field, RHO, 100.0, 0.0)
    rx = cam.expose(rate, T_EXP, rng)
    assert rx.max() < 255  # nothing saturated: the response alone bends the values
    files = {"sun": _png(d / "sun.png", cam.expose(cam.sun_rate(DNI, T_SUN), T_EXP, rng)),
             "rx": _png(d / "rx.png", rx), "amb": _png(d / "amb.png", cam.expose(0 * rate, T_EXP, rng))}
    inv = cam.sensor.inverse_response()
    save_crf(Crf.from_tables([inv, inv]), d / "crf.yaml")
    return files, str(d / "crf.yaml"), power


def test_crf_recovers_the_power_a_nonlinear_camera_bends(capsys, tmp_path, knee_scene):
    files, crf, power = knee_scene
    base = [files["rx"], "--sun", files["sun"], "--ambient", files["amb"], "--sun-transmittance", str(T_SUN),
            "--distance", "100", "--out", str(tmp_path / "f.npy")]
    code, raw, _ = _flux(capsys, *base)
    assert code == 0
    code, lin, _ = _flux(capsys, *base, "--crf", crf)
    assert code == 0 and lin["saturated_px"] == 0
    raw_err = raw["total_power_w"] / power - 1
    lin_err = lin["total_power_w"] / power - 1
    assert abs(raw_err) > 0.05  # the knee compresses the beam more than the sun disc's rim
    assert abs(lin_err) < 0.02, (raw_err, lin_err)


def test_saturated_receiver_is_refused_unless_allowed(capsys, tmp_path, camera, beam, rng):
    field, _ = beam(peak_w_m2=600e3)
    rate = camera.target_rate(field, RHO, 100.0, 0.0)
    sun = _png(tmp_path / "sun.png", camera.expose(camera.sun_rate(DNI, T_SUN), T_EXP, rng))
    rx_img = camera.expose(rate, 8 * T_EXP, rng)
    n_sat = int(np.count_nonzero(rx_img == 255))
    assert n_sat > 50
    rx = _png(tmp_path / "rx.png", rx_img)
    out = tmp_path / "f.npy"
    argv = [rx, "--sun", sun, "--exposure-ratio", "8", "--sun-transmittance", str(T_SUN), "--out", str(out)]
    code, res, _ = _flux(capsys, *argv)
    assert code == 2 and res["ok"] is False
    assert res["error"].startswith(f"{rx}: {n_sat} receiver pixels saturated")
    assert "--allow-saturated" in res["error"]
    assert not out.exists()
    code, res, err = _flux(capsys, *argv, "--allow-saturated")
    assert code == 0 and res["saturated_px"] == n_sat and out.exists()
    assert f"{n_sat} receiver pixels saturated (allowed)" in err


def test_pair_saturated_in_both_is_refused_and_counted(capsys, tmp_path, camera, beam, rng):
    field, _ = beam(peak_w_m2=600e3)
    rate = camera.target_rate(field, RHO, 100.0, 0.0)
    sun = _png(tmp_path / "sun.png", camera.expose(camera.sun_rate(DNI, T_SUN), T_EXP, rng))
    low_img, high_img = camera.expose(rate, 6e-3, rng), camera.expose(rate, 1.2e-2, rng)
    assert np.count_nonzero(low_img == 255) > 0  # even the short exposure clips the core
    low, high = _png(tmp_path / "low.png", low_img), _png(tmp_path / "high.png", high_img)
    argv = ["--receiver-pair", low, high, "--exposures", "0.006", "0.012", "--sun-exposure", "0.001",
            "--sun", sun, "--sun-transmittance", str(T_SUN), "--out", str(tmp_path / "f.npy")]
    code, res, _ = _flux(capsys, *argv)
    assert code == 2 and "receiver pixels saturated" in res["error"] and low in res["error"]
    code, res, _ = _flux(capsys, *argv, "--allow-saturated")
    assert code == 0 and res["saturated_px"] > 0


def test_crf_refusals(capsys, tmp_path, knee_scene):
    files, crf, _ = knee_scene
    flt = tmp_path / "rx.npy"
    np.save(flt, cv2.imread(files["rx"], cv2.IMREAD_UNCHANGED).astype(np.float32))
    out = str(tmp_path / "f.npy")
    code, res, _ = _flux(capsys, str(flt), "--sun", files["sun"], "--crf", crf, "--out", out)
    assert code == 2 and res["error"].startswith(f"{flt}: --crf needs integer pixels")
    code, res, _ = _flux(capsys, files["rx"], "--sun", files["sun"], "--crf", crf, "--dark-offset", "8",
                         "--out", out)
    assert code == 2 and "--dark-offset" in res["error"]
