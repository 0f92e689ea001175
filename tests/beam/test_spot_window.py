"""The default energy centroid (controller/imaging/spot_centroid.py) near the view's edges and
with a second beam in view: a spot whose light is all in the view is measured although its
window is cut by the edge; a spot running out of the view is reported ``clipped``; another beam
in view is reported (``second_spot_px``), not averaged in."""

from __future__ import annotations

import numpy as np
import pytest
from beamkit import gaussian

from controller.imaging.beam import analyze

SHAPE = (192, 256)


def _frame(spots, seed=0, tilt=(0.08, -0.05)) -> np.ndarray:
    """A tilted pedestal (counts per px along x and y) with 2-count noise and Gaussian spots
    (x, y, σ, amplitude)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.indices(SHAPE, dtype=float)
    img = 60.0 + tilt[0] * xx + tilt[1] * yy + rng.normal(0.0, 2.0, SHAPE)
    for x, y, s, a in spots:
        img += gaussian(SHAPE, x, y, s, amp=a)
    return img


@pytest.mark.parametrize("seed", range(3))
def test_a_spot_near_the_edge_is_measured_though_its_window_is_cut(seed):
    # σ 6 px at 20 px from the left edge: the 4 σ window is cut by the edge, the spot's light is
    # all in the view; the tilted pedestal is the background surface's to remove.
    r = analyze(_frame([(20.0, 96.0, 6.0, 120.0)], seed))
    assert r.clipped == ()
    assert np.hypot(r.centroid_px[0] - 20.0, r.centroid_px[1] - 96.0) < 0.15, r.centroid_px


def test_a_spot_running_out_of_the_view_is_reported_clipped():
    r = analyze(_frame([(7.0, 96.0, 6.0, 120.0)]))
    assert r.clipped == ("left",)
    r = analyze(_frame([(128.0, SHAPE[0] - 6.0, 6.0, 120.0)]))
    assert r.clipped == ("bottom",)


def test_a_second_beam_in_view_is_reported_not_averaged_in():
    r = analyze(_frame([(70.0, 90.0, 6.0, 120.0), (200.0, 120.0, 6.0, 100.0)]))
    assert np.hypot(r.centroid_px[0] - 70.0, r.centroid_px[1] - 90.0) < 0.15, r.centroid_px
    assert r.second_spot_px is not None and np.hypot(r.second_spot_px[0] - 200.0,
                                                     r.second_spot_px[1] - 120.0) < 4.0

