"""HDR merge: the table gather equals a plain float64 Eq. (1); uncovered pixels; input checks."""

import numpy as np
import pytest

from controller.errors import InputError
from controller.imaging import weights as W
from controller.imaging.crf import Crf
from controller.imaging.hdr import HdrMerger, estimate_noise_model
from simplant.devices.sensor import SensorModel, knee_response


def plain_eq1(z1, z2, t1, t2, inv1, inv2, wname, dark=8.0):
    """Eq. (1) written out per pixel in float64, independently of the merger's code."""
    out = np.full(z1.shape, np.nan)
    w_of = {
        "raised-cosine": lambda z, inv: W.raised_cosine(z, dark),
        "robertson": lambda z, inv: np.exp(-4 * (z - 127.5) ** 2 / 127.5**2),
        "debevec": lambda z, inv: np.where(z <= 127.5, z / 127.5, (255 - z) / 127.5),
        "mitsunaga": lambda z, inv: np.where(z < 255, z / 255, 0.0),
        "reinhard": lambda z, inv: np.where(z < 255, z / 255 * (1 - (z / 127.5 - 1) ** 12), 0.0),
        "deneve": lambda z, inv: np.where(z < 255, np.exp(-np.abs(z - 127.5) / 127.5), 0.0),
        "noise-optimal": lambda z, inv: W.noise_optimal(z, inv, dark),
    }[wname]
    a = z1.astype(float)
    b = z2.astype(float)
    w1 = w_of(a, inv1)
    w2 = w_of(b, inv2)
    num = w1 * t1 * inv1[z1] + w2 * t2 * inv2[z2]
    den = w1 * t1**2 + w2 * t2**2
    ok = den > 0
    out[ok] = num[ok] / den[ok]
    return out, ok


@pytest.fixture
def mismatched_crf():
    s1 = SensorModel(response=knee_response(0.15), gain=1.0)
    s2 = SensorModel(response=knee_response(0.25), gain=1.03)
    return Crf.from_tables([s1.inverse_response(), s2.inverse_response()])


@pytest.mark.parametrize("wname", W.NAMES)
def test_table_merge_equals_plain_eq1_on_all_pairs(wname, mismatched_crf):
    z1, z2 = np.meshgrid(np.arange(256, dtype=np.uint8), np.arange(256, dtype=np.uint8), indexing="ij")
    t = (0.010, 0.020)
    m = HdrMerger(t, mismatched_crf, wname, 8.0)
    got = m.merge(z1, z2)
    assert got.dtype == np.float32 and got.shape == (256, 256)
    ref, covered = plain_eq1(z1, z2, *t, mismatched_crf.inverse(0), mismatched_crf.inverse(1), wname)
    # The documented consistency rule replaces Eq. (1) where HIGH is at or below the dark offset.
    check = covered & (z2 > 8)
    assert check.sum() > 60000
    rel = np.abs(got[check] - ref[check]) / np.maximum(np.abs(ref[check]), 1e-30)
    assert rel.max() < 1e-5
    assert np.all(np.isfinite(got))


def test_linear_default_and_wide_ratio():
    z1 = np.array([[100, 50]], dtype=np.uint8)
    z2 = np.array([[200, 100]], dtype=np.uint8)
    m = HdrMerger((0.002, 0.032), None, "raised-cosine", 8.0)
    # I(z) = z; hand: pixel 1: w1 = w(100), w2 = w(200)
    w1, w2 = W.raised_cosine(100.0), W.raised_cosine(200.0)
    exp = (w1 * 0.002 * 100 + w2 * 0.032 * 200) / (w1 * 0.002**2 + w2 * 0.032**2)
    assert m.merge(z1, z2)[0, 0] == pytest.approx(exp, rel=1e-6)


def test_uncovered_pixels_are_finite_flagged_and_bounded():
    crf = Crf.linear(8, dark_offset=8.0)
    m = HdrMerger((0.010, 0.020), crf, "raised-cosine", 8.0)
    low = np.array([[255, 5, 100, 40]], dtype=np.uint8)
    high = np.array([[255, 6, 200, 4]], dtype=np.uint8)
    r = m.merge_with_mask(low, high)
    assert np.all(np.isfinite(r.hdr))
    assert r.valid.tolist() == [[False, False, True, False]]
    assert r.saturated_both == 1 and r.dark_both == 2
    assert r.hdr[0, 0] == pytest.approx(247 / 0.010)   # lower bound from the shorter exposure
    assert r.hdr[0, 1] == 0.0                          # I(6) = 0 from the longer exposure
    assert r.hdr[0, 3] == 0.0                          # HIGH dark: LOW's 40 is not trusted


@pytest.mark.parametrize("wname", W.NAMES)
def test_never_nan_or_inf(wname):
    z1, z2 = np.meshgrid(np.arange(256, dtype=np.uint8), np.arange(256, dtype=np.uint8), indexing="ij")
    for crf in (None, Crf.linear(8, 8.0)):
        out = HdrMerger((0.01, 0.02), crf, wname).merge(z1, z2)
        assert np.all(np.isfinite(out))


def test_high_bit_depth_path_matches_plain_eq1():
    rng = np.random.default_rng(3)
    z1 = rng.integers(0, 4096, (64, 64)).astype(np.uint16)
    z2 = rng.integers(0, 4096, (64, 64)).astype(np.uint16)
    m = HdrMerger((0.01, 0.03), None, "raised-cosine", 32.0, bit_depth=12)
    got = m.merge(z1, z2)
    w1 = W.raised_cosine(z1, 32.0, 12)
    w2 = W.raised_cosine(z2, 32.0, 12)
    den = w1 * 0.01**2 + w2 * 0.03**2
    ok = (den > 0) & (z2 > 32)
    ref = (w1 * 0.01 * z1 + w2 * 0.03 * z2)[ok] / den[ok]
    assert np.allclose(got[ok], ref, rtol=1e-6)


@pytest.mark.parametrize("low, high, msg", [
    (np.zeros((4, 4), np.uint8), np.zeros((4, 5), np.uint8), "differ in size"),
    (np.zeros((4, 4), np.float32), np.zeros((4, 4), np.uint8), "integer"),
    (np.full((4, 4), 300, np.uint16), np.zeros((4, 4), np.uint8), "outside 0..255"),
    (np.zeros((2, 4, 4), np.uint8), np.zeros((2, 4, 4), np.uint8), "2-D"),
])
def test_bad_inputs(low, high, msg):
    with pytest.raises(InputError, match=msg):
        HdrMerger().merge(low, high)


@pytest.mark.parametrize("kw, msg", [
    ({"exposures": (0.02, 0.01)}, "LOW <= HIGH"),
    ({"exposures": (0.0, 0.01)}, "positive"),
    ({"weighting": "gauss"}, "unknown weighting"),
    ({"dark_offset": 200.0}, "dark offset"),
])
def test_bad_merger_settings(kw, msg):
    with pytest.raises(InputError, match=msg):
        HdrMerger(**kw)


def test_estimate_noise_model_recovers_read_noise_and_conversion():
    s = SensorModel(read_noise=1.5, full_well=12000.0)
    rng = np.random.default_rng(0)
    scene = np.tile(np.linspace(0, 20000, 64), (32, 1))
    frames = np.stack([s.expose(scene, 0.01, rng) for _ in range(40)])
    read, k = estimate_noise_model(frames, 8.0)
    assert read == pytest.approx(1.5, rel=0.15)
    assert k == pytest.approx(12000.0 / 247.0, rel=0.1)


def test_merge_with_mask_matches_merge_and_from_camera_config():
    from controller.config import Camera

    cam = Camera(sensors=({"name": "a", "exposure_s": 0.005}, {"name": "b", "exposure_s": 0.04}),
                 dark_offset_counts=6.0)
    m = HdrMerger.from_camera_config(cam)
    assert m.exposures == (0.005, 0.04) and m.dark_offset == 6.0
    rng = np.random.default_rng(4)
    low = rng.integers(0, 256, (30, 40)).astype(np.uint8)
    high = rng.integers(0, 256, (30, 40)).astype(np.uint8)
    r = m.merge_with_mask(low, high)
    assert np.array_equal(r.hdr, m.merge(low, high))
    assert r.valid.sum() + r.saturated_both + r.dark_both == low.size


def test_from_camera_config_takes_every_camera_setting():
    from controller.config import Camera

    cam = Camera(sensors=({"name": "a", "exposure_s": 0.005}, {"name": "b", "exposure_s": 0.04}),
                 dark_offset_counts=6.0, read_noise_counts=2.0, full_well_electrons=5000.0)
    m = HdrMerger.from_camera_config(cam, None, "noise-optimal", exposures=(0.01, 0.02))
    plain = HdrMerger((0.01, 0.02), None, "noise-optimal", 6.0, bit_depth=cam.bit_depth, read_noise=2.0,
                      full_well=5000.0)
    assert m.exposures == (0.01, 0.02) and m.weighting == "noise-optimal"
    for a, b in zip(m.weights, plain.weights, strict=True):
        np.testing.assert_array_equal(a, b)
    default_noise = HdrMerger((0.01, 0.02), None, "noise-optimal", 6.0)
    assert not np.array_equal(m.weights[1], default_noise.weights[1])


def test_pair_bit_depth():
    from controller.imaging.hdr import pair_bit_depth

    u8 = np.zeros((2, 2), np.uint8)
    assert pair_bit_depth(u8, u8) == 8
    assert pair_bit_depth(np.array([[4095]], np.uint16), np.array([[7]], np.uint16)) == 12
    assert pair_bit_depth(np.array([[3]], np.uint16), np.array([[7]], np.uint16)) == 8
    assert pair_bit_depth(np.array([[4095]], np.uint16), u8, Crf.linear(10)) == 10
    assert pair_bit_depth(np.full((2, 2), np.nan), u8) == 8  # the merge then names the bad type


def test_merge_above_offset_removes_the_offset_exactly():
    from controller.imaging.hdr import merge_above_offset

    # A noise-free linear pair: z = offset + E t, so the merge above the offset is E itself.
    e = np.linspace(100.0, 9000.0, 60).reshape(6, 10)
    t = (0.01, 0.02)
    low, high = (np.round(8.0 + e * tk).astype(np.uint8) for tk in t)
    ok = (high < 250) & (low > 9)
    x = merge_above_offset(low, high, t, 8.0)
    np.testing.assert_allclose(x[ok], e[ok], rtol=0.05)
    assert np.max(np.abs(x[ok] - e[ok])) < 0.5 / t[0]  # within one count's quantisation
