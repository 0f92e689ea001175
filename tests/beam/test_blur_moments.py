"""Moment invariants to blur (controller/imaging/blur_moments.py, recognition/blur_features.py):
a synthetic asymmetric spot blurred by discs and Gaussians keeps its blur-hu features while
multi-hu's move; an asymmetric PSF changes them; the blur-hu library kinds build, save, load and
match through the CLI contract."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import yaml
from beamkit import cli, gaussian

from controller.imaging.blur_moments import blur_invariant_hu, energy_moments
from controller.imaging.moments import central_moments
from controller.recognition.blur_features import blur_features
from controller.recognition.features import describe, library_width

SHAPE = (200, 200)


def spot() -> np.ndarray:
    """An elongated spot with two side lobes, no mirror symmetry (so phi_3..phi_7 are not ~0)."""
    return 1000.0 * (gaussian(SHAPE, 95, 100, 14, 7) + gaussian(SHAPE, 118, 88, 5, 5, 0.6)
                     + gaussian(SHAPE, 85, 114, 4, 6, 0.4))


def pedestal() -> np.ndarray:
    yy, xx = np.mgrid[0:SHAPE[0], 0:SHAPE[1]].astype(float)
    return 20.0 + 8.0 * xx / SHAPE[1] + 4.0 * yy / SHAPE[0]


def disc(r: int) -> np.ndarray:
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    k = (xx**2 + yy**2 <= r * r).astype(float)
    return k / k.sum()


def gauss(s: float) -> np.ndarray:
    g = np.exp(-0.5 * (np.arange(-int(4 * s), int(4 * s) + 1) / s) ** 2)
    k = np.outer(g, g)
    return k / k.sum()


def ramp(length: int) -> np.ndarray:
    """A one-sided smear whose weight grows along +x: not centrosymmetric (mu_30(h) != 0)."""
    k = np.zeros((2 * length + 1, 2 * length + 1))
    k[length, length:] = np.arange(1, length + 2)
    return k / k.sum()


def other_spot() -> np.ndarray:
    """A second case: a rounder spot with one lobe."""
    return 1000.0 * (gaussian(SHAPE, 98, 100, 9, 8) + gaussian(SHAPE, 112, 104, 5, 5, 0.7))


def blurred(kernel: np.ndarray, f: np.ndarray | None = None) -> np.ndarray:
    f = spot() if f is None else f
    return cv2.filter2D(f, -1, kernel, borderType=cv2.BORDER_CONSTANT) + pedestal()


SYMMETRIC = {"gauss 1.5 px": gauss(1.5), "gauss 3 px": gauss(3.0), "disc r 3 px": disc(3),
             "disc r 6 px": disc(6)}


def test_convolution_theorem_on_whole_image():
    # Flusser & Suk Eq. 5 with a centrosymmetric unit-mass h: third-order and mixed second-order
    # central moments per unit energy unchanged, mu20/mu00 and mu02/mu00 grow by sigma^2.
    f = spot()
    a = central_moments(f)
    b = central_moments(cv2.filter2D(f, -1, gauss(3.0), borderType=cv2.BORDER_CONSTANT))
    for k in ("30", "21", "12", "03", "11"):
        assert b.mu[k] / b.m00 == pytest.approx(a.mu[k] / a.m00, rel=1e-6, abs=1e-6)
    var = float((gauss(3.0).sum(axis=0) * np.arange(-12, 13) ** 2).sum())  # the sampled kernel's sigma^2
    assert b.mu["20"] / b.m00 - a.mu["20"] / a.m00 == pytest.approx(var, rel=1e-6)


def test_blur_hu_invariant_to_symmetric_blur_while_multi_hu_moves():
    base = blur_invariant_hu(spot() + pedestal())
    base_b = blur_features(base)
    base_m = describe(spot() + pedestal(), "multi-hu")
    for name, k in SYMMETRIC.items():
        img = blurred(k)
        phi = blur_invariant_hu(img)
        # phi_2, phi_3 (the largest invariants) within 1 %; the whole feature vector within 0.003
        # (it is a unit vector), with the background estimated from the image and a window.
        assert np.all(np.abs(phi[1:3] / base[1:3] - 1) < 0.01), name
        assert np.max(np.abs(blur_features(phi) - base_b)) < 0.003, name
        # phi_1 is not invariant: it grows with the blur.
        assert phi[0] > base[0], name
        # The thresholded Hu moments move by more than 1.5 % (at 0.1 of the peak) for every kernel.
        moved = np.abs(describe(img, "multi-hu")[:, 0] / base_m[:, 0] - 1)
        assert moved.max() > 0.015, name


def test_blur_hu_changes_under_an_asymmetric_psf():
    base = blur_invariant_hu(spot() + pedestal())
    sym = max(float(np.max(np.abs(blur_features(blur_invariant_hu(blurred(k))) - blur_features(base))))
              for k in SYMMETRIC.values())
    phi = blur_invariant_hu(blurred(ramp(16)))
    # An anisotropic, one-sided PSF moves phi_2 (its mu20 - mu02 is not zero) and the third order.
    assert abs(phi[1] / base[1] - 1) > 0.1
    assert float(np.max(np.abs(blur_features(phi) - blur_features(base)))) > 3 * sym


def test_blur_features_scale_and_brightness_free():
    f = spot() + pedestal()
    big = cv2.resize(spot(), None, fx=1.5, fy=1.5, interpolation=cv2.INTER_CUBIC)
    big = big[50:250, 50:250] * 0.5 + pedestal()  # zoomed 1.5x (spot stays in frame), half as bright
    np.testing.assert_allclose(blur_features(blur_invariant_hu(big)), blur_features(blur_invariant_hu(f)),
                               atol=0.01)
    # c_pq of the zoomed spot scale as 1.5^(p+q).
    c0, c1 = energy_moments(f), energy_moments(big)
    assert c1["11"] / c0["11"] == pytest.approx(1.5**2, rel=0.02)


def test_library_widths_and_descriptor_rows():
    img = spot() + pedestal()
    assert describe(img, "blur-hu").shape == (1, 7)
    assert describe(img, "multi-blur-hu").shape == (4, 7)
    widths = (library_width("blur-hu"), library_width("multi-blur-hu"), library_width("multi-hu"))
    assert widths == (6, 27, 21)


@pytest.mark.parametrize("kind", ["blur-hu", "multi-blur-hu"])
def test_blur_kinds_through_the_cli(tmp_path, capsys, kind):
    # Two cases, each at two blurs; a third blur (a disc) of each, turned by 90 degrees, is recognised.
    imgs = {"a0": blurred(gauss(1.0)), "a1": blurred(gauss(2.5)),
            "b0": blurred(gauss(1.0), other_spot()), "b1": blurred(gauss(2.5), other_spot())}
    for name, img in imgs.items():
        np.save(tmp_path / f"{name}.npy", img.astype(np.float32))
    (tmp_path / "lib.csv").write_text("image,label,az_deg,el_deg\n" + "".join(
        f"{n}.npy,{n[0]},," + "\n" for n in imgs), encoding="utf-8")
    lib = str(tmp_path / "lib.yaml")
    code, out, err = cli(capsys, "library", "build", str(tmp_path / "lib.csv"), "--out", lib,
                         "--features", kind, "--json")
    assert code == 0, err
    assert json.loads(out)["features"] == kind
    for label, f in (("a", spot()), ("b", other_spot())):
        np.save(tmp_path / "q.npy", np.rot90(blurred(disc(4), f)).astype(np.float32))
        code, out, err = cli(capsys, "match", str(tmp_path / "q.npy"), "--library", lib, "--json")
        assert code == 0, err
        assert json.loads(out)["label"] == label


def test_blur_library_file_validated(tmp_path, capsys):
    imgs = {"a0": blurred(gauss(1.0)), "b0": blurred(gauss(1.0), other_spot())}
    for name, img in imgs.items():
        np.save(tmp_path / f"{name}.npy", img.astype(np.float32))
    (tmp_path / "lib.csv").write_text("image,label,az_deg,el_deg\na0.npy,a,,\nb0.npy,b,,\n", encoding="utf-8")
    lib = tmp_path / "lib.yaml"
    code, _, err = cli(capsys, "library", "build", str(tmp_path / "lib.csv"), "--out", str(lib),
                       "--features", "multi-blur-hu")
    assert code == 0, err
    doc = yaml.safe_load(lib.read_text(encoding="utf-8"))
    assert doc["thresholds"] == [0.1, 0.3, 0.5, 0.05] and len(doc["entries"][0]["features"]) == 27
    doc["thresholds"] = [0.1, 0.3, 0.5]
    lib.write_text(yaml.safe_dump(doc), encoding="utf-8")
    np.save(tmp_path / "q.npy", imgs["a0"].astype(np.float32))
    code, _, err = cli(capsys, "match", str(tmp_path / "q.npy"), "--library", str(lib))
    assert code == 2
    assert "thresholds" in err and str(lib) in err and len(err.strip().splitlines()) == 1
