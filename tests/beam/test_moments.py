"""Hu moments against hand-computed values, exact arithmetic, OpenCV, and the documented pitfalls."""

from __future__ import annotations

from fractions import Fraction

import cv2
import numpy as np
import pytest
from beamkit import skewed_blob

from controller.imaging.moments import hu_moments, normalise_intensity


@pytest.mark.parametrize("a,b", [(40, 20), (31, 7), (16, 16)])
def test_uniform_rectangle_matches_closed_form(a, b):
    # A pixel rectangle a wide, b high: mu20 = b * a(a^2-1)/12, mu02 = a * b(b^2-1)/12, mu00 = ab, so
    # phi1 = ((a^2-1) + (b^2-1)) / (12 a b) and phi2 = ((a^2 - b^2) / (12 a b))^2; phi3..7 = 0 (symmetric).
    img = np.zeros((60, 80))
    img[10:10 + b, 5:5 + a] = 1.0
    phi = hu_moments(img)
    assert phi[0] == pytest.approx(((a * a - 1) + (b * b - 1)) / (12 * a * b), rel=1e-12)
    assert phi[1] == pytest.approx(((a * a - b * b) / (12 * a * b)) ** 2, rel=1e-12, abs=1e-18)
    assert np.all(np.abs(phi[2:]) < 1e-15)


def test_large_disc_approaches_continuous_value():
    # Uniform disc: mu20 = mu02 = pi R^4 / 4, mu00 = pi R^2 -> phi1 = 1 / (2 pi).
    img = np.zeros((401, 401), np.uint8)
    cv2.circle(img, (200, 200), 180, 1, -1)
    assert hu_moments(img)[0] == pytest.approx(1 / (2 * np.pi), rel=2e-4)


def _exact_hu(img: np.ndarray) -> list[Fraction]:
    """Hu (1962) from exact rational central moments (independent, slow reference)."""
    rows, cols = img.shape
    f = [[Fraction(int(img[y, x])) for x in range(cols)] for y in range(rows)]
    m00 = sum(sum(r) for r in f)
    cx = sum(f[y][x] * x for y in range(rows) for x in range(cols)) / m00
    cy = sum(f[y][x] * y for y in range(rows) for x in range(cols)) / m00

    def mu(p, q):
        return sum(f[y][x] * (x - cx) ** p * (y - cy) ** q for y in range(rows) for x in range(cols))

    def eta(p, q):
        return float(mu(p, q)) / float(m00) ** ((p + q) / 2 + 1)

    n20, n02, n11 = eta(2, 0), eta(0, 2), eta(1, 1)
    n30, n03, n21, n12 = eta(3, 0), eta(0, 3), eta(2, 1), eta(1, 2)
    a, b = n30 + n12, n21 + n03
    return [n20 + n02, (n20 - n02) ** 2 + 4 * n11 ** 2, (n30 - 3 * n12) ** 2 + (3 * n21 - n03) ** 2,
            a * a + b * b,
            (n30 - 3 * n12) * a * (a * a - 3 * b * b) + (3 * n21 - n03) * b * (3 * a * a - b * b),
            (n20 - n02) * (a * a - b * b) + 4 * n11 * a * b,
            (3 * n21 - n03) * a * (a * a - 3 * b * b) - (n30 - 3 * n12) * b * (3 * a * a - b * b)]


def test_agrees_with_exact_rational_reference():
    rng = np.random.default_rng(3)
    img = rng.integers(0, 50, size=(9, 12))
    img[2:5, 3:10] += 200  # an off-centre bar makes every invariant non-zero
    np.testing.assert_allclose(hu_moments(img), _exact_hu(img), rtol=1e-9)


@pytest.mark.parametrize("seed", range(5))
def test_agrees_with_opencv_float64(seed):
    img = skewed_blob(seed=seed)
    ours = hu_moments(img)
    ref = cv2.HuMoments(cv2.moments(img.astype(np.float64))).ravel()
    np.testing.assert_allclose(ours[:4], ref[:4], rtol=1e-9)
    np.testing.assert_allclose(ours[4:], ref[4:], rtol=1e-6)


def test_brightness_scaling_exponents():
    # Pitfall: grey-level Hu moments scale with intensity k as k^-[1, 2, 3, 3, 6, 4, 6].
    img = skewed_blob(seed=1)
    k = 3.0
    ratio = hu_moments(k * img) / hu_moments(img)
    np.testing.assert_allclose(ratio, k ** -np.array([1, 2, 3, 3, 6, 4, 6], float), rtol=1e-9)


def test_unit_mean_normalisation_removes_brightness_but_keeps_zoom_invariance():
    img = skewed_blob(seed=2)
    img[img < 0.05 * img.max()] = 0.0
    a = hu_moments(normalise_intensity(img))
    b = hu_moments(normalise_intensity(7.5 * img))
    np.testing.assert_allclose(a, b, rtol=1e-12)
    # A 2x zoom (each pixel -> 2x2 block) keeps the grey image's mean over the spot, so phi1 and
    # phi2 stay (up to the pixel-size term of the discrete sums, well below 1 %).
    zoom = np.kron(img, np.ones((2, 2)))
    np.testing.assert_allclose(hu_moments(normalise_intensity(zoom))[:2], a[:2], rtol=1e-2)


def test_mirroring_flips_phi7_only():
    img = skewed_blob(seed=4)
    a, m = hu_moments(img), hu_moments(img[:, ::-1])
    np.testing.assert_allclose(m[:6], a[:6], rtol=1e-9)
    assert m[6] == pytest.approx(-a[6], rel=1e-6)


def test_rotation_by_90_degrees_and_translation_are_invariant():
    img = skewed_blob(seed=5)
    np.testing.assert_allclose(hu_moments(np.rot90(img)), hu_moments(img), rtol=1e-9)
    shifted = np.zeros((200, 260))
    shifted[37:157, 61:221] = img
    np.testing.assert_allclose(hu_moments(shifted), hu_moments(img), rtol=1e-9)


def test_pedestal_dominates_phi1():
    # Pitfall: a 0.1 % pedestal on a 1024x768 frame changes phi1 by far more than 100 %.
    from beamkit import gaussian

    spot = gaussian((768, 1024), 500.3, 380.7, 12.0)
    assert hu_moments(spot + 1e-3)[0] > 2.0 * hu_moments(spot)[0]


def test_float32_input_is_summed_in_float64():
    img = skewed_blob(shape=(768, 1024), seed=6).astype(np.float32)
    ref = cv2.HuMoments(cv2.moments(img.astype(np.float64))).ravel()
    np.testing.assert_allclose(hu_moments(img)[:4], ref[:4], rtol=1e-9)


def test_zero_image_is_rejected():
    with pytest.raises(ValueError):
        hu_moments(np.zeros((4, 4)))
