"""Weighting functions against values computed by hand from their definitions."""

import math

import numpy as np
import pytest

from controller.imaging import weights as W

C = 127.5


@pytest.mark.parametrize("z, expected", [
    (127.5, 1.0),        # centre
    (120.0, 1.0),        # low side flat part: |z - c| <= c(1 - β)/2 = a = 8
    (119.5, 1.0),
    (63.75, 0.5),        # middle of the low roll-off [8, 119.5]
    (8.0, 0.0),          # at the dark offset
    (3.0, 0.0),          # below it
    (191.25, 0.5),       # high side, β = 1: ½[1 + cos(π · 63.75 / 127.5)]
    (255.0, 0.0),        # saturated
    (254.0, 0.5 * (1 + math.cos(math.pi * 126.5 / 127.5))),
])
def test_raised_cosine_hand_values(z, expected):
    assert W.raised_cosine(z, dark_offset=8.0) == pytest.approx(expected, abs=1e-12)


def test_raised_cosine_generalises_to_12_bits():
    c = 4095 / 2
    assert W.raised_cosine(c, dark_offset=32.0, bit_depth=12) == pytest.approx(1.0)
    assert W.raised_cosine(4095, dark_offset=32.0, bit_depth=12) == pytest.approx(0.0)
    assert W.raised_cosine(32, dark_offset=32.0, bit_depth=12) == 0.0
    # midpoint of the low roll-off [a, c - a] is 0.5
    assert W.raised_cosine((32 + c - 32) / 2, dark_offset=32.0, bit_depth=12) == pytest.approx(0.5)


def test_classic_weights_hand_values():
    assert W.robertson(C) == pytest.approx(1.0)
    assert W.robertson(0) == pytest.approx(math.exp(-4))
    assert W.debevec(C) == pytest.approx(1.0)
    assert W.debevec(63.75) == pytest.approx(0.5)
    assert W.debevec(255) == 0.0
    assert W.mitsunaga(51) == pytest.approx(0.2)
    assert W.mitsunaga(255) == 0.0
    assert W.reinhard(C) == pytest.approx(0.5)   # (127.5/255) [1 - 0^12]
    assert W.reinhard(255) == 0.0
    assert W.reinhard(0) == 0.0
    assert W.deneve(C) == pytest.approx(1.0)
    assert W.deneve(0) == pytest.approx(math.exp(-1))
    assert W.deneve(0, a=0.5, b=2.0) == pytest.approx(math.exp(-0.5))
    assert W.deneve(C + 63.75, a=2.0) == pytest.approx(math.exp(-0.25))
    assert W.deneve(255) == 0.0


def test_deneve_emphasises_the_middle_and_ignores_saturation():
    """The paper's description: an exponential power function peaking in the middle, in [0, 1],
    symmetric about c, zero for saturated pixels (the garbled table entry was none of these)."""
    z = np.arange(256.0)
    for a, b in ((1.0, 1.0), (2.0, 0.5), (4.0, 0.1)):
        w = W.deneve(z, a=a, b=b)
        assert w.max() <= 1.0 and w.min() >= 0.0
        assert w[255] == 0.0 and w[254] > 0.0
        assert np.argmax(w) in (127, 128)
        assert np.all(np.diff(w[:128]) > 0) and np.all(np.diff(w[128:255]) < 0)
        assert np.allclose(w[1:128], w[254:127:-1])  # w(z) = w(255 - z) below saturation
    with pytest.raises(ValueError):
        W.deneve(z, a=0.0)


def test_noise_optimal_is_inverse_variance_of_linear_sensor():
    # Linear sensor with I(z) = z - a: var I = (z - a) ΔI / FW + r² + 1/12 with ΔI = 247, FW = k·247.
    z = np.arange(256.0)
    inv = np.maximum(z - 8.0, 0.0)
    k = 20000.0 / 247.0
    w = W.noise_optimal(z, inv, dark_offset=8.0, read_noise=0.8, electrons_per_count=k, taper_sigmas=0)
    for zz in (20, 100, 200, 250):
        var = (zz - 8.0) * 247.0 / 20000.0 + 0.64 + 1 / 12
        assert w[zz] == pytest.approx(1.0 / var, rel=1e-9)
    assert w[255] == 0.0 and w[8] == 0.0 and w[0] == 0.0


def test_noise_optimal_taper_only_near_limits():
    z = np.arange(256.0)
    inv = np.maximum(z - 8.0, 0.0)
    bare = W.noise_optimal(z, inv, taper_sigmas=0)
    tapered = W.noise_optimal(z, inv, taper_sigmas=3)
    assert np.allclose(bare[20:240], tapered[20:240])
    assert 0 < tapered[9] < bare[9] and 0 < tapered[254] < bare[254]


def test_weight_table_names_and_unknown():
    for name in W.NAMES:
        t = W.weight_table(name)
        assert t.shape == (256,) and np.all(np.isfinite(t)) and np.all(t >= 0)
    with pytest.raises(ValueError, match="unknown weighting"):
        W.weight_table("gaussian")
