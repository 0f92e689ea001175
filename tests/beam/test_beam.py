"""Beam analysis: centroid convention, hand-computed ellipse and d90, background handling, bad input."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from beamkit import cli, gaussian, heliocal

from controller.errors import InputError
from controller.imaging.background import estimate_background
from controller.imaging.beam import analyze, enclosed_energy_diameter


def test_single_pixel_centroid_is_column_row():
    img = np.zeros((10, 12))
    img[3, 7] = 5.0
    r = analyze(img, threshold=0.5, background="none")
    assert r.centroid_px == (7.0, 3.0)
    assert r.peak == 5.0 and r.total == 5.0


def test_gaussian_centroid_is_subpixel_exact():
    # A sampled Gaussian well inside the frame has its intensity centroid at its centre.
    img = gaussian((120, 160), 71.37, 48.81, 6.0)
    r = analyze(img, threshold=0.0, background="none")
    assert r.centroid_px == pytest.approx((71.37, 48.81), abs=1e-6)
    # With the default threshold the symmetric cut keeps the centre too.
    assert analyze(img).centroid_px == pytest.approx((71.37, 48.81), abs=0.02)


@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.uint16])
def test_analyze_leaves_its_input_alone(dtype):
    # A float64 crop used to be a view: the background was subtracted from the caller's image,
    # so a second analysis of the same array saw a different image.
    img = (gaussian((120, 160), 70.0, 50.0, 6.0, amp=1000.0) + 40.0 + 0.1 * np.arange(160)).astype(dtype)
    before = img.copy()
    first = analyze(img, background="auto")
    np.testing.assert_array_equal(img, before)
    again = analyze(img, background="auto")
    assert again.centroid_px == first.centroid_px and again.total == first.total
    np.testing.assert_array_equal(again.hu, first.hu)


@pytest.mark.parametrize("shape", [(96, 128), (480, 640)])
def test_the_auto_plane_is_the_one_estimated_on_the_image_whether_or_not_presence_fitted_it(shape):
    # A small float32 image is its own presence level: the plane fitted there is the one
    # estimate_background gives the image; a larger one is reduced first and fits its own.
    rng = np.random.default_rng(5)
    rows, cols = shape
    img = (gaussian(shape, 0.45 * cols, 0.55 * rows, rows / 16, amp=800.0) + 60.0 + 0.05 * np.arange(cols)
           + rng.normal(0.0, 2.0, shape)).astype(np.float32)
    auto = analyze(img, background="auto", centroid="segment")
    given = analyze(img, background=estimate_background(img), centroid="segment")
    assert auto.background == given.background
    assert auto.centroid_px == given.centroid_px and auto.total == given.total
    np.testing.assert_array_equal(auto.hu, given.hu)


def test_uniform_disc_ellipse_and_d90():
    # Uniform disc radius R: variance R^2/4 per axis -> full axes 4 sqrt(R^2/4) = 2R;
    # enclosed energy grows as r^2, so d90 = 2 R sqrt(0.9).
    radius = 40
    img = np.zeros((200, 200))
    cv2.circle(img, (90, 110), radius, 1.0, -1)
    r = analyze(img, background="none")
    assert r.centroid_px == pytest.approx((90.0, 110.0), abs=1e-9)
    assert r.ellipse.major_px == pytest.approx(2 * radius, rel=0.01)
    assert r.ellipse.minor_px == pytest.approx(2 * radius, rel=0.01)
    assert r.d90_px == pytest.approx(2 * radius * np.sqrt(0.9), abs=0.6)
    assert r.pixels == pytest.approx(np.pi * radius**2, rel=0.01)


@pytest.mark.parametrize("angle", [0.0, 25.0, -60.0])
def test_rotated_ellipse_axes_and_angle(angle):
    # cv2.ellipse draws with angle from +x towards +y (down the image), our convention too.
    img = np.zeros((240, 240), np.uint8)
    cv2.ellipse(img, (120, 120), (60, 24), angle, 0, 360, 200, -1)
    r = analyze(img, background="none")
    # cv2 draws the boundary pixels too, so the pixel ellipse is ~1 px longer on each axis.
    assert r.ellipse.major_px == pytest.approx(120, abs=1.5)
    assert r.ellipse.minor_px == pytest.approx(48, abs=1.5)
    assert r.ellipse.angle_deg == pytest.approx(angle, abs=0.5)


def test_enclosed_energy_of_two_points():
    # Two equal points at distances 1 and 3 from the centre: 90 % needs the outer one.
    w = np.zeros((7, 7))
    w[3, 4] = 1.0
    w[3, 6] = 1.0
    assert enclosed_energy_diameter(w, 3.0, 3.0, 0.4) == pytest.approx(2.0, abs=0.05)
    assert enclosed_energy_diameter(w, 3.0, 3.0, 0.9) == pytest.approx(6.0, abs=0.05)


def test_auto_background_removes_tilted_pedestal():
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:300, 0:400].astype(float)
    pedestal = 50.0 + 0.05 * xx - 0.03 * yy
    img = pedestal + gaussian((300, 400), 250.4, 120.6, 10.0, amp=400.0) + rng.normal(0, 2.0, (300, 400))
    r = analyze(img)
    assert r.centroid_px == pytest.approx((250.4, 120.6), abs=0.05)
    assert r.background.slope_x == pytest.approx(0.05, abs=0.002)
    assert r.background.slope_y == pytest.approx(-0.03, abs=0.002)
    # Without subtraction the pedestal is part of the "spot" moments and the shape is wrong.
    clean = analyze(gaussian((300, 400), 250.4, 120.6, 10.0, amp=400.0), background="none")
    assert r.hu[0] == pytest.approx(clean.hu[0], rel=0.01)
    assert abs(r.hu[1] - clean.hu[1]) < 1e-5  # both ~0 for a round spot


def test_null_image_background_and_mask():
    spot = gaussian((100, 100), 30.0, 60.0, 5.0, amp=100.0)
    glare = gaussian((100, 100), 80.0, 20.0, 4.0, amp=300.0)  # brighter, off target
    ambient = np.full((100, 100), 20.0)
    mask = np.zeros((100, 100), bool)
    mask[:, :60] = True
    r = analyze(spot + glare + ambient, background=ambient, mask=mask)
    assert r.centroid_px == pytest.approx((30.0, 60.0), abs=0.01)


def test_hot_pixel_does_not_set_the_threshold():
    img = gaussian((100, 100), 40.0, 50.0, 6.0, amp=100.0)
    img[5, 90] = 1000.0  # one hot pixel, ten times the spot's peak
    r = analyze(img, background="none")
    assert r.centroid_px == pytest.approx((40.0, 50.0), abs=0.05)


@pytest.mark.parametrize("image,message", [
    (np.zeros((0, 5)), "empty"),
    (np.zeros((20, 20)), "all zeros"),
    (np.full((20, 20), 255, np.uint8), "saturated"),
    (np.zeros((4, 4, 2)), "2-D"),
    (np.full((8, 8), np.nan), "NaN"),
])
def test_bad_images_raise_input_error(image, message):
    with pytest.raises(InputError, match=message):
        analyze(image)


def test_bad_threshold_and_mask_shape():
    img = gaussian((50, 50), 25, 25, 4)
    with pytest.raises(InputError, match="threshold"):
        analyze(img, threshold=1.5)
    with pytest.raises(InputError, match="mask shape"):
        analyze(img, mask=np.ones((10, 10)))


def test_cli_json_contract_and_plots(tmp_path):
    img = (gaussian((80, 100), 60.25, 30.5, 5.0, amp=200.0) + 10).astype(np.uint8)
    path = tmp_path / "spot.png"
    cv2.imwrite(str(path), img)
    plots = tmp_path / "plots"
    r = heliocal("beam", str(path), "--plot", str(plots), "--json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert set(d) == {"centroid_px", "peak", "total", "pixels", "hu", "ellipse", "d90_px", "saturated_px",
                      "beam", "statistic", "statistic_name", "threshold", "clipped", "second_spot_px"}
    assert d["beam"] is True and d["statistic"] >= d["threshold"] == 5.5
    assert d["clipped"] == [] and d["second_spot_px"] is None
    assert set(d["ellipse"]) == {"major_px", "minor_px", "angle_deg"}
    assert len(d["hu"]) == 7
    assert d["centroid_px"] == pytest.approx([60.25, 30.5], abs=0.15)
    assert len(list(plots.glob("*.png"))) == 6


@pytest.mark.parametrize("kind", ["empty", "zeros", "saturated", "shape", "corrupt", "missing"])
def test_cli_bad_input_exit_2_one_line(tmp_path, capsys, kind):
    path = tmp_path / ("img.npy" if kind in ("empty", "shape") else "img.png")
    if kind == "empty":
        np.save(path, np.zeros((0, 0)))
    elif kind == "zeros":
        cv2.imwrite(str(path), np.zeros((30, 30), np.uint8))
    elif kind == "saturated":
        cv2.imwrite(str(path), np.full((30, 30), 255, np.uint8))
    elif kind == "shape":
        np.save(path, np.ones((3, 30, 30)))
    elif kind == "corrupt":
        path.write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 10)
    plots = tmp_path / "plots"
    code, _, err = cli(capsys, "beam", str(path), "--plot", str(plots))
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert path.name in err or kind in ("zeros", "saturated")
    assert not plots.exists()
    code, out, _ = cli(capsys, "beam", str(path), "--json")
    assert code == 2 and json.loads(out)["ok"] is False


def test_corrupt_file_gives_one_line_from_the_console_script(tmp_path):
    # OpenCV's own stderr logging must not add lines to our one-line error.
    path = tmp_path / "bad.png"
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 10)
    r = heliocal("beam", str(path))
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [f"heliocal beam: error: {path}: not a readable image "
                                             "(corrupt file or unsupported format)"]


@pytest.mark.parametrize("kind", ["png16", "colour", "tiff32"])
def test_cli_reads_16bit_colour_and_float_tiff(tmp_path, capsys, kind):
    spot = gaussian((64, 96), 40.5, 22.25, 4.0)
    if kind == "png16":
        path = tmp_path / "s.png"
        cv2.imwrite(str(path), (spot * 60000 + 500).astype(np.uint16))
    elif kind == "colour":
        path = tmp_path / "s.png"
        grey = (spot * 200 + 20).astype(np.uint8)
        cv2.imwrite(str(path), np.dstack([grey, grey, grey]))
    else:
        path = tmp_path / "s.tiff"
        cv2.imwrite(str(path), (spot * 1e4).astype(np.float32))
    code, out, err = cli(capsys, "beam", str(path), "--json")
    assert code == 0, err
    assert json.loads(out)["centroid_px"] == pytest.approx([40.5, 22.25], abs=0.1)


def test_cli_names_the_file_of_an_empty_image(tmp_path):
    import subprocess
    import sys

    import cv2

    path = tmp_path / "dark.png"
    cv2.imwrite(str(path), np.zeros((40, 50), np.uint8))
    r = subprocess.run([sys.executable, "-m", "controller.cli", "beam", str(path)], capture_output=True,
                       text=True)
    assert r.returncode == 2 and f"{path}: image is all zeros" in r.stderr
