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
