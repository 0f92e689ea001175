"""Sensor model: mean, photon-transfer variance, saturation, gain, response inverse."""

import numpy as np
import pytest

from simplant.devices.sensor import SensorModel, knee_response, shot_law


def test_mean_and_variance_follow_photon_transfer():
    s = SensorModel(bit_depth=8, dark_offset=8.0, read_noise=0.8, full_well=20000.0)
    rng = np.random.default_rng(0)
    z = s.expose(np.full((400, 500), 1000.0), 0.1, rng).astype(float)  # 100 linear counts
    assert z.mean() == pytest.approx(108.0, abs=0.02)
    k = 20000.0 / 247.0
    expected_var = 0.8**2 + 100.0 / k + 1 / 12  # read + shot (s/k counts²) + quantisation
    assert z.var() == pytest.approx(expected_var, rel=0.04)


def test_saturation_reads_exactly_z_max_and_dtype():
    s = SensorModel()
    z = s.expose(np.full((50, 50), 1e7), 0.01, np.random.default_rng(1))
    assert z.dtype == np.uint8 and np.all(z == 255)
    s12 = SensorModel(bit_depth=12, dark_offset=32.0)
    z12 = s12.expose(np.full((10, 10), 1e9), 0.01, np.random.default_rng(1))
    assert z12.dtype == np.uint16 and np.all(z12 == 4095)


def test_dark_frame_sits_at_offset():
    z = SensorModel().expose(np.zeros((300, 300)), 0.02, np.random.default_rng(2)).astype(float)
    assert z.mean() == pytest.approx(8.0, abs=0.02)


def test_gain_mismatch_scales_linear_signal():
    s = SensorModel(gain=1.03, read_noise=0.0)
    assert s.expected_value(5000.0, 0.02) == pytest.approx(8.0 + 100.0 * 1.03)


def test_knee_response_and_its_inverse():
    f = knee_response(0.2)
    assert f(0.0) == 0.0 and f(1.0) == pytest.approx(1.0) and f(0.5) == pytest.approx(0.6 / 1.1)
    s = SensorModel(response=f, gain=1.1)
    inv = s.inverse_response()
    assert inv.shape == (256,) and np.all(np.diff(inv) >= 0) and np.all(inv[:9] == 0)
    # expected_value(I / t, t) must return z: the table is the exact inverse.
    for z in (20, 100, 200, 254):
        assert s.expected_value(inv[z] / 0.01, 0.01) == pytest.approx(z, abs=1e-3)


def _exact_counts(s: SensorModel, electrons_mean: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """The sensor pipeline of simplant.devices.sensor's docstring written out with Poisson shot noise
    (an independent reference for the Gaussian approximation)."""
    e = np.minimum(rng.poisson(electrons_mean, n), s.full_well)
    z = s.dark_offset + s.span * s.response(e / s.full_well) + rng.normal(0.0, s.read_noise, n)
    z = np.clip(np.rint(z), 0, s.z_max)
    z[e >= s.full_well] = s.z_max
    return z.astype(int)


@pytest.mark.parametrize("electrons", [0.0, 0.5, 5.0, 50.0, 500.0, 5000.0, 19000.0, 19800.0, 20000.0,
                                       30000.0])
def test_gaussian_shot_noise_matches_poisson_in_output_counts(electrons):
    # The demo camera's sensor (8-bit, 0.8 counts read noise = 65 e-): whatever the signal,
    # the counts it outputs have the distribution of the exact Poisson pipeline.
    s = SensorModel(read_noise=0.8, response=knee_response(0.25), gain=1.03, shot="gauss")
    n, t = 200_000, 0.01
    irradiance = np.full((400, n // 400), electrons / (t * s.gain * s.electrons_per_count))
    fast = s.expose(irradiance, t, np.random.default_rng(1)).astype(int).ravel()
    exact = _exact_counts(s, electrons, n, np.random.default_rng(2))
    p, q = np.bincount(fast, minlength=256) / n, np.bincount(exact, minlength=256) / n
    assert 0.5 * np.abs(p - q).sum() < 0.01  # total variation; sampling alone gives ~0.003
    se = np.sqrt((fast.var() + exact.var()) / n)
    assert abs(fast.mean() - exact.mean()) <= 5 * se + 1e-9
    assert fast.std() == pytest.approx(exact.std(), rel=0.01, abs=1e-3)


def test_shot_law_uses_gauss_only_behind_enough_read_noise():
    assert shot_law(0.8, 20000.0, 8, 8.0) == "gauss"  # the demo camera: 65 e- read noise
    assert shot_law(0.8, 20000.0, 12, 32.0) == "poisson"  # 12-bit: 4 e-, Poisson shows
    assert shot_law(0.0, 20000.0, 8, 8.0) == "poisson"
    with pytest.raises(ValueError, match="shot"):
        SensorModel(shot="uniform")
