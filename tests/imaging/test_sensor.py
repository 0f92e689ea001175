"""Sensor model: mean, photon-transfer variance, saturation, gain, response inverse."""

import numpy as np
import pytest

from simplant.sensor import SensorModel, knee_response


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
