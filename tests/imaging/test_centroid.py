"""Energy centroid: hand-computed cases, clipping, and the beam check on a noise-only frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from controller.imaging.centroid import energy_centroid

REPO = Path(__file__).resolve().parents[2]


def test_two_lobes_by_hand():
    s = np.zeros((20, 30))
    s[5, 4] = 3.0  # (x=4, y=5) weight 3
    s[12, 20] = 1.0  # (x=20, y=12) weight 1, a dim lobe above the 5 % threshold
    c = energy_centroid(s, 0.05, smooth_sigma_px=0.5)
    assert c.x == pytest.approx((3 * 4 + 20) / 4) and c.y == pytest.approx((3 * 5 + 12) / 4)
    assert c.total == pytest.approx(4.0) and c.clipped == ()


def test_edges_touched_are_reported():
    s = np.zeros((10, 10))
    s[0, 5] = s[5, 9] = 1.0
    assert set(energy_centroid(s, 0.05, 0.5).clipped) == {"top", "right"}


def test_nothing_above_threshold_gives_nan():
    c = energy_centroid(np.zeros((8, 8)), 0.05)
    assert np.isnan(c.x) and c.total == 0.0


def test_noise_only_frame_is_no_beam_not_a_clipped_one():
    """The heliostat at stow leaves only noise: the chain says there is no beam, with figures."""
    from controller.calibration.cycle.beam_chain import BeamChain
    from controller.calibration.cycle.observations import NoBeam
    from controller.config import load_config

    chain = BeamChain(load_config(REPO / "configs" / "demo.yaml"))
    noise = np.random.default_rng(0).normal(20.0, 1.0, (768, 1024))
    with pytest.raises(NoBeam, match=r"^no beam on the target \(no beam: spot excess .* x the") as e:
        chain.analyze(noise)
    assert e.value.statistic < e.value.threshold == 5.5
    spot = noise.copy()
    yy, xx = np.mgrid[0:768, 0:1024]
    spot += 500.0 * np.exp(-((xx - 400.0) ** 2 + (yy - 300.0) ** 2) / (2 * 15.0**2))
    obs = chain.analyze(spot)
    assert obs.centroid_px == pytest.approx((400, 300), abs=0.5)


def test_beam_chain_centroid_is_the_energy_centroid_of_both_lobes():
    """A dim detached lobe (canting error) is outside analyze()'s main region but pulls the aim."""
    from controller.calibration.cycle.beam_chain import BeamChain
    from controller.calibration.cycle.observations import BeamNotFound
    from controller.config import load_config
    from controller.imaging.background import subtract_background
    from controller.imaging.beam import analyze

    chain = BeamChain(load_config(REPO / "configs" / "demo.yaml"))
    yy, xx = np.mgrid[0:768, 0:1024]
    img = 20.0 + np.random.default_rng(1).normal(0.0, 1.0, xx.shape)
    img += 800.0 * np.exp(-((xx - 400.0) ** 2 + (yy - 300.0) ** 2) / (2 * 12.0**2))
    img += 200.0 * np.exp(-((xx - 520.0) ** 2 + (yy - 330.0) ** 2) / (2 * 10.0**2))
    obs = chain.analyze(img)
    r = analyze(img, threshold=chain.threshold, background="auto")
    c = energy_centroid(subtract_background(img, r.background), chain.centroid_threshold)
    assert obs.centroid_px == (c.x, c.y)
    assert c.x - r.centroid_px[0] > 5.0  # the main-region centroid ignores the lobe
    edge = img.copy()
    edge += 800.0 * np.exp(-((xx - 2.0) ** 2 + (yy - 300.0) ** 2) / (2 * 12.0**2))
    with pytest.raises(BeamNotFound, match="^beam spot clipped by the left edge of the camera view$"):
        chain.analyze(edge)


def test_noise_specks_at_a_dim_spots_threshold_do_not_pull_its_centroid():
    """Two frames recorded on the 10,000-heliostat simulated field (tests/data/beams): a small dim
    spot alone in an 8-bit camera's view, its 5 % threshold a few σ above the background, where a
    dozen noise specks reach it. Weighed in, they pulled the centroid 2.4 and 10.8 px (0.9 and
    4.0 m) towards the view's centre, and the models refitted on those centroids sent beams
    metres off; only the parts of the mask that rise SPECK_SIGMAS σ above the background weigh
    in now, and both centroids are within 0.15 px of the plant's true hit. A detached lobe of the
    beam still counts (test_two_lobes_by_hand and the chain's two-lobe test above)."""
    from controller.calibration.cycle.beam_chain import BeamChain
    from controller.config import load_config
    from controller.imaging.background import subtract_background
    from controller.imaging.beam import analyze
    from controller.imaging.centroid import SPECK_SIGMAS

    d = np.load(REPO / "tests" / "data" / "beams" / "dim_spots_alone.npz")
    chain = BeamChain(load_config(REPO / "configs" / "demo.yaml"))  # the field's calibration settings
    for hdr, (tx, ty) in zip(d["hdr"].astype(float), d["truth_px"], strict=True):
        r = analyze(hdr, threshold=chain.threshold, background="auto")
        signal = subtract_background(hdr, r.background)
        every = energy_centroid(signal, chain.centroid_threshold)
        kept = energy_centroid(signal, chain.centroid_threshold, min_sigmas=SPECK_SIGMAS)
        assert np.hypot(every.x - tx, every.y - ty) > 2.0  # the defect, as recorded
        assert np.hypot(kept.x - tx, kept.y - ty) < 0.15
        assert kept.clipped == () and kept.total < every.total


def test_significant_keeps_the_peak_and_every_part_that_rises_above_the_floor():
    from controller.imaging.centroid import significant

    smooth = np.zeros((10, 12))
    smooth[2, 2], smooth[2, 9], smooth[7, 5:7] = 5.0, 2.0, 1.5  # the peak, a lobe, a speck
    mask = smooth > 1.0
    assert np.array_equal(significant(smooth, mask, 1.8), (smooth > 1.9))  # the speck goes
    assert np.array_equal(significant(smooth, mask, 9.0), smooth == 5.0)  # the peak's part stays
    assert np.array_equal(significant(smooth, mask, 0.5), mask)


def test_significant_is_the_per_part_maximum_rule_on_random_noise():
    """Each 8-connected part kept exactly when its own maximum of ``smooth`` is above the floor,
    or when it holds the mask's peak (the first such part by label, as ``argmax`` of the parts'
    maxima): checked against ndimage's per-label maximum on masks of many parts."""
    from scipy import ndimage

    from controller.imaging.centroid import significant

    rng = np.random.default_rng(7)
    for trial in range(40):
        smooth = rng.normal(size=(24, 32)).astype(np.float32)
        if trial % 4 == 0:
            smooth = np.round(smooth)  # ties: several parts at the peak
        mask = smooth > 0.8
        labels, n = ndimage.label(mask, structure=np.ones((3, 3), bool))
        assert n > 1
        high = np.asarray(ndimage.maximum(smooth, labels, np.arange(1, n + 1)), float)
        floor = float(np.quantile(high, 0.6))
        keep = high > floor
        keep[int(np.argmax(high))] = True
        want = np.concatenate([[False], keep])[labels]
        assert np.array_equal(significant(smooth, mask, floor), want)
