"""The centre of a spot clipped by the view's edge (controller.calibration.clipped_spot) and the
coarse correction that puts it on the aim in the loop, against the centroid-only loop."""

from __future__ import annotations

import numpy as np
import pytest

from controller.calibration.clipped_spot import BEYOND, EXTRAPOLATED, clipped_centre
from controller.calibration.observations import Observation
from controller.imaging.centroid import energy_centroid

from .conftest import AIM

W, H = 160, 120  # view, px
PITCH_M = 0.05  # m per px: the view is 8 m x 6 m about the aim point
THRESHOLD = 0.05  # calibration.centroid_threshold of the demo


def spot(cx: float, cy: float, sx: float = 8.0, sy: float = 8.0) -> np.ndarray:
    """A Gaussian spot centred at (cx, cy) px (may lie outside the view), σ (sx, sy) px."""
    y, x = np.mgrid[0:H, 0:W]
    return (1000.0 * np.exp(-0.5 * (((x - cx) / sx) ** 2 + ((y - cy) / sy) ** 2))).astype(np.float32)


def centre_of(img: np.ndarray):
    c = energy_centroid(img, THRESHOLD)
    return c, clipped_centre(img, THRESHOLD, c.clipped, (c.x, c.y))


@pytest.mark.parametrize("cx, cy, edges", [
    (5.0, 60.0, ("left",)),  # the core is cut: half width borrowed from the rows
    (155.0, 60.0, ("right",)),
    (80.0, 115.0, ("bottom",)),
    (6.0, 18.0, ("top", "left")),  # only the tails cut at the top: the rows' half width is known
])
def test_a_clipped_round_spot_is_found_where_it_is_and_the_centroid_is_not(cx, cy, edges):
    c, (est, conf) = centre_of(spot(cx, cy))
    assert set(c.clipped) == set(edges)
    bias = np.hypot(c.x - cx, c.y - cy)
    assert bias > 2.0  # what the centroid-only move gets wrong
    assert np.hypot(est[0] - cx, est[1] - cy) < min(0.2 * bias, 1.0)
    assert conf == EXTRAPOLATED  # the clipped side's half width came from the other axis


def test_a_centre_beyond_the_edge_is_a_lower_bound_with_low_confidence():
    c, (est, conf) = centre_of(spot(-6.0, 60.0))
    bias = abs(c.x + 6.0)
    assert bias > 8.0 and conf == BEYOND
    assert -6.0 < est[0] < 0.0 and abs(est[0] + 6.0) < 0.25 * bias  # short, but far nearer


def test_only_the_tails_clipped_gives_the_half_maximum_midpoint_with_full_confidence():
    c, (est, conf) = centre_of(spot(20.0, 60.0))  # 2.5 σ from the edge: the 5 % mask touches it
    assert c.clipped == ("left",)
    assert conf == 1.0 and abs(est[0] - 20.0) < 0.3 and abs(est[1] - 60.0) < 0.3


def test_an_elongated_spot_whose_borrowed_half_width_is_too_small_falls_back_to_the_centroid():
    # The half width along x is twice the one along y: far crossing − the rows' half width lies
    # inside the visible centroid, so the estimate is the centroid (never further inside).
    c, (est, conf) = centre_of(spot(8.0, 60.0, sx=16.0, sy=8.0))
    assert conf == EXTRAPOLATED and est[0] == pytest.approx(c.x)


def test_no_estimate_when_the_spot_overflows_both_sides_or_is_empty():
    wide = spot(80.0, 60.0, sx=200.0, sy=8.0)  # wider than the view
    c, (est, conf) = centre_of(wide)
    assert {"left", "right"} <= set(c.clipped) and est is None and conf == 0.0
    assert clipped_centre(np.zeros((H, W), np.float32), THRESHOLD, ("left",), (0.0, 0.0)) == (None, 0.0)


def test_the_estimate_is_never_further_inside_than_the_centroid_nor_beyond_one_view():
    img = spot(2.0, 60.0)
    c = energy_centroid(img, THRESHOLD)
    (x, _), _ = clipped_centre(img, THRESHOLD, c.clipped, (c.x, c.y))
    assert -W <= x <= c.x
    # A (faked) centroid further out than the half-maximum midpoint: the centroid bounds it.
    (x2, _), _ = clipped_centre(img, THRESHOLD, c.clipped, (-1.0, c.y))
    assert x2 == -1.0


# -- in the loop: the fake plant's spot rendered into the 8 m x 6 m view about the aim -----------
def _px(east_m: float, up_m: float) -> tuple[float, float]:
    return (W - 1) / 2 + east_m / PITCH_M, (H - 1) / 2 - up_m / PITCH_M


def _enu(x: float, y: float) -> tuple[float, float, float]:
    return tuple(AIM + np.array([(x - (W - 1) / 2) * PITCH_M, 0.0, ((H - 1) / 2 - y) * PITCH_M]))


def _analyze_rendered(frame) -> Observation:
    """The beam chain's analysis (energy centroid, clipped edges, clipped centre) of the spot the
    fake plant's beam offset makes in the view."""
    img = spot(*_px(*frame.metadata["offset"]))
    c, (centre, conf) = centre_of(img)
    return Observation((c.x, c.y), _enu(c.x, c.y), np.ones(7), 1.0, tuple(c.clipped),
                       _enu(*centre) if centre is not None else None, conf)


@pytest.mark.parametrize("hidden_az_steps, threshold", [
    (18500, 0.5), (19300, 0.5),  # 3.70 m / 3.86 m east: the spot's core is cut, its peak in view
    (20800, 0.25),  # 4.16 m: the centre beyond the edge (a lower bound, confidence 0.25)
])
def test_a_clipped_first_look_converges_in_fewer_looks_with_the_coarse_correction(make_cycle, hidden_az_steps,
                                                                                   threshold):
    # Tolerance 2 mrad (12 cm at 58 m, 2.3 px): a move that puts the spot within it ends the
    # cycle at the next measurement; the fake plant's Jacobian is exact, so one centroid
    # move from a spot in full view always does.
    runs = {}
    for coarse in (None, threshold):
        cyc, plant, _ = make_cycle(hidden=(hidden_az_steps, 0), tolerance_mrad=2.0)
        cyc.ctx.analyze = _analyze_rendered
        cyc.ctx.coarse_confidence = coarse
        runs[coarse] = (cyc.run(), plant)
    (plain, plain_plant), (rec, plant) = runs[None], runs[threshold]
    assert plain.status == rec.status == "calibrated"
    # Both looked at a clipped spot first (a correction before any measurement) ...
    assert plain.corrections[0].iteration == 0 and rec.corrections[0].iteration == 0
    assert (plain.corrections[0].kind, rec.corrections[0].kind) == ("fine", "coarse")
    # ... the coarse move put the spot within tolerance, the centroid's fell short by metres.
    assert plant.true_errors[0] < 2.0 < plain_plant.true_errors[0]
    assert rec.iterations < plain.iterations and plant.captures < plain_plant.captures
    assert len(rec.corrections) < len(plain.corrections)


def test_an_unconfident_clipped_centre_is_not_applied(make_cycle):
    cyc, plant, _ = make_cycle(hidden=(18500, 0), tolerance_mrad=2.0)
    cyc.ctx.analyze = _analyze_rendered
    cyc.ctx.coarse_confidence = 0.9  # the estimate's confidence is 0.5: the centroid moves
    rec = cyc.run()
    assert [c.kind for c in rec.corrections] == ["fine"] * len(rec.corrections)
