"""The centre of a spot clipped by the view's edge (controller.imaging.clipped_spot) and the
coarse correction that puts it on the aim in the loop, against the centroid-only loop."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from controller.calibration.cycle.observations import Observation
from controller.imaging.centroid import energy_centroid
from controller.imaging.clipped_spot import BEYOND, CORE_CUT, clipped_centre
from tests.calibration.conftest import AIM

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
    assert conf == CORE_CUT  # the clipped side's half width came from the other axis


def test_a_centre_beyond_the_edge_is_a_rough_bounded_guess_with_low_confidence():
    c, (est, conf) = centre_of(spot(-6.0, 60.0))
    assert c.clipped == ("left",) and c.x - (-6.0) > 8.0 and conf == BEYOND
    # The visible maximum underestimates the peak: the half-maximum contour is too wide and the
    # guess overshoots, bounded by the spot's extent along the edge beyond the centroid.
    smooth = cv2.GaussianBlur(spot(-6.0, 60.0), (0, 0), 2.0)
    ys = np.nonzero(smooth > THRESHOLD * smooth.max())[0]
    assert c.x - (np.ptp(ys) + 1) <= est[0] < c.x


def test_an_elongated_spot_is_found_from_the_ellipse_of_its_visible_contour():
    # Half width along x twice the one along y, the core cut at the left edge.
    c, (est, conf) = centre_of(spot(8.0, 60.0, sx=16.0, sy=8.0))
    assert conf == CORE_CUT and abs(c.x - 8.0) > 5.0 and abs(est[0] - 8.0) < 0.5 and est[1] == c.y


def test_a_two_lobed_clipped_spot_fits_no_ellipse_and_is_not_trusted():
    # Two lobes (a split facet) cut by the left edge: the ellipse fits one of them only.
    img = spot(5.0, 40.0) + spot(5.0, 80.0)
    c, (est, conf) = centre_of(img)
    assert c.clipped == ("left",) and conf == BEYOND and est is not None


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
    img = spot(*_px(*frame.metadata["offset"]), sx=24.0, sy=12.0)  # 2.8 m x 1.4 m at half maximum
    c, (centre, conf) = centre_of(img)
    if not c.clipped:
        return Observation((c.x, c.y), _enu(c.x, c.y), np.ones(7), 1.0)
    return Observation((c.x, c.y), _enu(c.x, c.y), np.ones(7), 1.0, tuple(c.clipped),
                       _enu(*centre) if centre is not None else None, conf)


@pytest.mark.parametrize("hidden_az_steps", [16375, 17625])  # 3.28 m / 3.53 m east: the core is cut
def test_a_clipped_first_look_converges_in_fewer_looks_with_the_coarse_correction(make_cycle,
                                                                                   hidden_az_steps):
    # Tolerance 2 mrad (12 cm at 58 m, 2.3 px): a move that puts the spot within it ends the
    # cycle at the next measurement; the fake plant's Jacobian is exact, so one centroid
    # move from a spot in full view always does.
    runs = {}
    threshold = 0.5
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
    cyc, plant, _ = make_cycle(hidden=(16375, 0), tolerance_mrad=2.0)
    cyc.ctx.analyze = _analyze_rendered
    cyc.ctx.coarse_confidence = 0.9  # the estimate's confidence is 0.5: the centroid moves
    rec = cyc.run()
    assert [c.kind for c in rec.corrections] == ["fine"] * len(rec.corrections)


def test_the_beam_chain_gives_a_clipped_spot_its_centre_on_the_target():
    from controller.calibration.cycle.beam_chain import BeamChain
    from controller.config import load_config
    from tests.calibration.conftest import REPO

    chain = BeamChain(load_config(REPO / "configs" / "demo.yaml"))
    yy, xx = np.mgrid[0:768, 0:1024]
    img = 20.0 + np.random.default_rng(2).normal(0.0, 1.0, xx.shape)
    img += 800.0 * np.exp(-0.5 * (((xx - 1010.0) / 40.0) ** 2 + ((yy - 300.0) / 25.0) ** 2))
    obs = chain.analyze(img, allow_clipped=True)
    assert obs.clipped == ("right",) and obs.clipped_confidence == CORE_CUT
    true_enu = chain.frame.pixel_to_enu(1010.0, 300.0)
    err = np.linalg.norm(np.asarray(obs.clipped_centre_enu) - true_enu)
    assert err < 0.2 * np.linalg.norm(np.asarray(obs.centroid_enu) - true_enu)
    # A spot in full view carries no clipped centre.
    full = 20.0 + 800.0 * np.exp(-0.5 * (((xx - 500.0) / 40.0) ** 2 + ((yy - 300.0) / 25.0) ** 2))
    obs = chain.analyze(full)
    assert obs.clipped == () and obs.clipped_centre_enu is None and obs.clipped_confidence == 0.0
