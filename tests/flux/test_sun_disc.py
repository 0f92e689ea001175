"""Sun-disc detection on rendered discs (known centre and radius) and its refusals."""

import numpy as np
import pytest

from controller.flux.sun_disc import SunDiscError, find_sun_disc, saturation_level_for
from simplant.devices.sensor import SensorModel


def _image(disc_renderer, rng, shape, center, radius, peak=200.0, u=0.6):
    disc = disc_renderer(shape, center, radius, u)
    return SensorModel().expose(disc * peak / 1e-3, 1e-3, rng)


@pytest.mark.parametrize("radius", [6.0, 15.5, 40.2, 63.7])
@pytest.mark.parametrize("u", [0.0, 0.6])
def test_radius_and_centre_within_half_a_pixel(disc_renderer, rng, radius, u):
    shape = (int(2 * radius + 40), int(2 * radius + 60))
    center = (shape[1] / 2 + rng.uniform(-3, 3), shape[0] / 2 + rng.uniform(-3, 3))
    disc = find_sun_disc(_image(disc_renderer, rng, shape, center, radius, u=u))
    assert abs(disc.radius_px - radius) < 0.1  # quality bar is 0.5 px
    assert np.hypot(disc.center_px[0] - center[0], disc.center_px[1] - center[1]) < 0.1
    assert not disc.manual


@pytest.mark.parametrize("sigma", [0.7, 1.5, 3.0])
def test_radius_under_lens_blur(disc_renderer, rng, sigma):
    # A Gaussian lens blur of σ px must not move the radius (the sum is blur-invariant).
    from scipy import ndimage

    shape, center, radius = (160, 180), (90.3, 80.6), 30.0
    d = ndimage.gaussian_filter(disc_renderer(shape, center, radius), sigma)
    disc = find_sun_disc(SensorModel().expose(d * 200.0 / 1e-3, 1e-3, rng))
    assert abs(disc.radius_px - radius) < 0.3
    assert disc.sum_counts == pytest.approx(200.0 * d.sum(), rel=0.005)


def test_disc_sum_matches_the_rendered_signal(disc_renderer, rng):
    shape, center, radius = (160, 180), (91.3, 78.6), 35.0
    d = disc_renderer(shape, center, radius)
    img = SensorModel().expose(d * 200.0 / 1e-3, 1e-3, rng)
    disc = find_sun_disc(img)
    assert disc.sum_counts == pytest.approx(200.0 * d.sum(), rel=0.005)
    assert disc.background == pytest.approx(8.0, abs=0.6)  # the sensor's dark offset


def test_manual_override_is_used(disc_renderer, rng):
    img = _image(disc_renderer, rng, (160, 180), (91.3, 78.6), 35.0)
    disc = find_sun_disc(img, center_px=(91.0, 79.0), radius_px=35.5)
    assert disc.manual and disc.center_px == (91.0, 79.0) and disc.radius_px == 35.5
    with pytest.raises(SunDiscError, match="both"):
        find_sun_disc(img, radius_px=35.0)


def test_saturated_sun_is_refused(disc_renderer, rng):
    img = _image(disc_renderer, rng, (160, 180), (91.3, 78.6), 35.0, peak=400.0)
    with pytest.raises(SunDiscError, match="saturated"):
        find_sun_disc(img)
    # also with a manual disc
    with pytest.raises(SunDiscError, match="saturated"):
        find_sun_disc(img, center_px=(91.3, 78.6), radius_px=35.0)


def test_float_image_needs_an_explicit_saturation_level(disc_renderer, rng):
    img = _image(disc_renderer, rng, (160, 180), (91.3, 78.6), 35.0).astype(np.float32)
    assert saturation_level_for(img.dtype) is None
    find_sun_disc(img)
    with pytest.raises(SunDiscError, match="saturated"):
        find_sun_disc(img, saturation_level=150.0)


def test_missing_disc_is_refused(rng):
    img = SensorModel().expose(np.zeros((120, 160)), 1e-3, rng)
    with pytest.raises(SunDiscError, match="no sun disc"):
        find_sun_disc(img)


def test_disc_cut_by_the_border_is_refused(disc_renderer, rng):
    img = _image(disc_renderer, rng, (160, 180), (20.0, 80.0), 35.0)
    with pytest.raises(SunDiscError, match="border"):
        find_sun_disc(img)


def test_tiny_or_elongated_blob_is_refused(rng):
    img = np.full((120, 160), 8, np.uint8)
    img[60:62, 80:82] = 200
    with pytest.raises(SunDiscError, match="radius"):
        find_sun_disc(img)
    img = np.full((120, 160), 8, np.uint8)
    img[50:60, 30:130] = 200
    with pytest.raises(SunDiscError, match="round"):
        find_sun_disc(img)
