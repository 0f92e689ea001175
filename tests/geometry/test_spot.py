"""The spot on a target (controller.geometry.spot) and the tracking model for many poses at once
(controller.geometry.pose_batch): against the scalar model, by the equations' limits, and
against the simulated plant's independent truth."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from controller.config import parse_config
from controller.errors import LimitError
from controller.geometry import pose_batch
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model.tracking import (
    PRIOR_SIGMA_SI,
    TrackingModel,
    model_aim,
    model_mirror_center,
    model_normal,
)
from controller.geometry.spot import (
    MirrorOptics,
    PredictedSpot,
    park_clearance_m,
    predict_spots,
    spot_covariance,
)
from controller.geometry.target_frame import TargetFrame
from tests.calibration.conftest import REPO

N, U, V = np.array([0.0, 1.0, 0.0]), np.array([-1.0, 0.0, 0.0]), np.array([0.0, 0.0, -1.0])


@pytest.fixture(scope="module")
def cfg():
    return parse_config(yaml.safe_load((REPO / "configs" / "demo.yaml").read_text()), "demo.yaml")


def test_batched_aim_and_pose_equal_the_scalar_model(cfg):
    rng = np.random.default_rng(3)
    centre = np.asarray(cfg.target().center_enu_m, float)
    points = centre + np.array([[x, 0.0, z] for x in (-2.0, 0.0, 2.0) for z in (-1.5, 1.5)])
    for h in cfg.heliostats[::4]:
        kin = HeliostatKinematics.from_config(h)
        model = TrackingModel(rng.normal(0.0, PRIOR_SIGMA_SI))
        for lamp in (s for s in cfg.light_sources if s.kind == "lamp"):
            pos = np.asarray(lamp.position_enu_m, float)
            steps, ok = pose_batch.aim_steps(kin, model.values, points, lamp=pos)
            for k, p in enumerate(points):
                try:
                    want = model_aim(kin, model, None, p, lamp_position=pos)
                except (LimitError, ValueError):
                    assert not ok[k]
                    continue
                assert ok[k] and tuple(steps[k]) == want
            n, c = pose_batch.normal_and_center(kin, model.values[None, None], steps[ok])
            for k, st in enumerate(steps[ok]):
                assert n[0, k] == pytest.approx(model_normal(kin, model, *st), abs=1e-12)
                assert c[0, k] == pytest.approx(model_mirror_center(kin, model, *st), abs=1e-12)


def test_one_pose_of_one_model_equals_the_scalar_model_and_the_batch(cfg):
    """normal_and_center's float path (one pose, one model: beam-safety checks) against the
    scalar model and the array path, with a concentrator translation; a pose beyond the
    actuator triangle is NaN in both paths."""
    rng = np.random.default_rng(11)
    for h in cfg.heliostats[::3]:
        kin = HeliostatKinematics.from_config(h)
        kin = type(kin)(kin.heliostat_id, kin.position, kin.azimuth, kin.elevation, rng.normal(0.0, 0.3, 3))
        model = TrackingModel(rng.normal(0.0, PRIOR_SIGMA_SI))
        for st in rng.uniform([kin.azimuth.min_steps, kin.elevation.min_steps],
                              [kin.azimuth.max_steps, kin.elevation.max_steps], (5, 2)):
            n, c = pose_batch.normal_and_center(kin, model.values, st[None])
            assert n.shape == c.shape == (1, 3)
            assert n[0] == pytest.approx(model_normal(kin, model, *st), abs=1e-12)
            assert c[0] == pytest.approx(model_mirror_center(kin, model, *st), abs=1e-12)
            nb, cb = pose_batch.normal_and_center(kin, model.values, np.vstack([st, st]))
            assert n[0] == pytest.approx(nb[1], abs=1e-13) and c[0] == pytest.approx(cb[1], abs=1e-13)
        far = np.array([[kin.azimuth.max_increment * 50.0, kin.elevation.min_steps]])
        assert np.isnan(pose_batch.normal_and_center(kin, model.values, far)[0]).all()
        assert np.isnan(pose_batch.normal_and_center(kin, model.values, np.vstack([far, far]))[0]).all()


def test_a_stack_of_heliostats_with_concentrator_translations_poses_as_each_alone(cfg):
    """normal_and_center over a KinStack (the planner's and the lamp change's batches) with a
    concentrator translation per heliostat: each row is that heliostat's own pose."""
    rng = np.random.default_rng(12)
    kins = []
    for h in cfg.heliostats[:5]:
        k = HeliostatKinematics.from_config(h)
        kins.append(type(k)(k.heliostat_id, k.position, k.azimuth, k.elevation, rng.normal(0.0, 0.3, 3)))
    values = rng.normal(0.0, PRIOR_SIGMA_SI, (len(kins), 14))
    steps = np.array([[rng.uniform(k.azimuth.min_steps, k.azimuth.max_steps),
                       rng.uniform(k.elevation.min_steps, k.elevation.max_steps)] for k in kins])
    stack = pose_batch.KinStack.of(kins)
    n, c = pose_batch.normal_and_center(stack.shaped(2), values[:, None, :], steps[:, None, :])
    assert n.shape == c.shape == (len(kins), 1, 3)
    for i, k in enumerate(kins):
        model = TrackingModel(values[i])
        assert n[i, 0] == pytest.approx(model_normal(k, model, *steps[i]), abs=1e-12)
        assert c[i, 0] == pytest.approx(model_mirror_center(k, model, *steps[i]), abs=1e-12)


def test_spot_size_terms_and_their_limits():
    beam = np.array([0.0, -1.0, 0.0])  # head-on to a north-facing... plane whose normal is N
    # A mirror focused on the target, without slope error: only the lamp's disc, σ = αL/4.
    only_lamp = spot_covariance(100.0, 2e-3, 0.0, 3.0, 2.0, 100.0, beam, N, U, V)
    assert np.sqrt(np.diag(only_lamp)) == pytest.approx([0.05, 0.05])
    # Slope error alone: σ = 2 σ_s L.
    slope = spot_covariance(100.0, 0.0, 1e-3, 3.0, 2.0, 100.0, beam, N, U, V)
    assert np.sqrt(np.diag(slope)) == pytest.approx([0.2, 0.2])
    # Defocus alone: a band of width w|1 − L/f|, σ = that / √12, along each mirror axis.
    flat = spot_covariance(100.0, 0.0, 0.0, 3.0, 2.0, 50.0, beam, N, U, V)
    assert np.sqrt(np.diag(flat)) == pytest.approx([3.0 / math.sqrt(12), 2.0 / math.sqrt(12)])
    # Independent blurs add in quadrature.
    both = spot_covariance(100.0, 2e-3, 1e-3, 3.0, 2.0, 100.0, beam, N, U, V)
    assert both[0, 0] == pytest.approx(only_lamp[0, 0] + slope[0, 0])
    # A beam at 60° to the normal, tilted along u, stretches the spot by 2 along u only.
    tilted = np.array([-math.sin(math.radians(60)), -math.cos(math.radians(60)), 0.0])
    long = spot_covariance(100.0, 0.0, 1e-3, 3.0, 2.0, 100.0, tilted, N, U, V)
    assert np.sqrt(np.diag(long)) == pytest.approx([0.4, 0.2])


def test_in_view_is_eq_4_on_both_axes():
    spots = PredictedSpot(np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 2.5]]), np.array([[0.5, 0.3]] * 3),
                          np.array([[0.2, 0.1]] * 3))
    # reach = |o| + 3 (σ + σ_pos): 1 + 2.1 = 3.1 along u; 2.5 + 1.2 = 3.7 along v for the third.
    assert spots.reach_m()[0] == pytest.approx([3.1, 1.2])
    assert spots.in_view([3.3, 3.5], 0.2).tolist() == [True, True, False]
    assert spots.in_view([3.29, 3.5], 0.2).tolist() == [False, False, False]


def test_park_clearance_is_the_fixed_point_of_the_spot_sized_where_it_parks():
    """c = H + 3 s(c) + m from the view's edge: a spot that grows aside (s = a + b c,
    3b < 0.8) converges to (H + 3a + m) / (1 − 3b), the geometric tail included; one that grows
    too fast (3b ≥ 0.8: hardly or no clearance holds at 3σ) keeps its size beside the view's
    edge, H + 3 s(H + m) + m, or what it had reached when it stopped converging; one out of
    reach aside (NaN) has no park beside the view (+∞)."""
    a = np.array([0.5, 0.5, 0.5, 0.1])
    b = np.array([0.05, 0.2, 0.3, 0.0])

    def size_at(c):
        return np.where(np.arange(4) == 3, np.nan, a + b * c)

    c = park_clearance_m(size_at, 4.0, 0.5, (4,))
    assert c[0] == pytest.approx((4.0 + 1.5 + 0.5) / (1 - 0.15), abs=0.02)
    assert c[1] == pytest.approx((4.0 + 1.5 + 0.5) / (1 - 0.6), abs=0.05)
    assert c[2] == pytest.approx(4.0 + 3 * (0.5 + 0.3 * 4.5) + 0.5)
    assert c[3] == np.inf
    # steps 1.5, then 1.0 (shrinking), then 1.2 (growing again): it keeps the 7.0 m reached, not c₁ = 6.0
    late = park_clearance_m(lambda c: np.interp(c, [4.5, 6.0, 7.0, 100.0], [0.5, 2.5 / 3, 3.7 / 3, 40.0]),
                            4.0, 0.5)
    assert float(late) == pytest.approx(7.0)


def test_a_spot_out_of_reach_at_the_views_edge_parks_where_it_is_in_reach_and_sized():
    """Issue 42: a heliostat that cannot aim at either side of the view's edge has no spot size
    there; its clearance was the edge itself plus the margin, as if its spot were a point, and
    a 10,000-heliostat night parked such spots 0.5 m beside the view. Now its park starts at the
    first probe beyond the edge in reach (``PARK_PROBES_M``) and holds c ≥ H + 3 s(c) + m there;
    one in reach nowhere aside has none (+∞)."""
    from controller.geometry.spot import PARK_PROBES_M

    reach_from = np.array([4.5, 6.0, 7.5, 4.5 + PARK_PROBES_M[-1] + 1.0])  # view edge H + m = 4.5

    def size_at(c):
        return np.where(c >= reach_from, 0.4 + 0.01 * c, np.nan)

    c = park_clearance_m(size_at, 4.0, 0.5, (4,))
    assert c[0] == pytest.approx(4.0 + 3 * (0.4 + 0.01 * c[0]) + 0.5, abs=0.02)  # as before
    there = size_at(np.where(np.isfinite(c), c, 0.0))
    assert np.all(c[1:3] >= reach_from[1:3]) and np.all(np.isfinite(there[:3]))
    assert np.all(c[:3] >= 4.0 + 3 * there[:3] + 0.5 - 0.02)  # sized where it parks
    assert c[3] == np.inf


def test_a_parked_spots_position_counts_at_four_sigma_its_size_at_three(cfg, monkeypatch):
    """The park clearance takes the spot's position at PARK_POSITION_SIGMAS (4) σ of the
    covariance: with the prior's covariance it lies about one σ of the parked spot's position
    farther out than at 3σ (a calibrated model's covariance, a tenth of the prior's: the
    clearance converges); without position uncertainty the two agree."""
    from controller.geometry import spot as spot_mod
    from controller.geometry.pose_batch import KinStack

    frame = TargetFrame.from_config(cfg.target(), (cfg.camera.height_px, cfg.camera.width_px))
    lamp = cfg.light_source()
    pos = np.asarray(lamp.position_enu_m, float)
    h = cfg.heliostat("H13")
    kin = KinStack.of([HeliostatKinematics.from_config(h)])
    optics = MirrorOptics.stack([h.mirror])
    values = TrackingModel.zero().values[None]
    got = {}
    for scale in (0.0, 0.1):
        cov = np.diag((scale * PRIOR_SIGMA_SI) ** 2)[None]
        for k in (4.0, 3.0):
            monkeypatch.setattr(spot_mod, "PARK_POSITION_SIGMAS", k)
            got[scale, k] = float(spot_mod.park_clearances_m(kin, optics, values, cov, frame, 0.5, lamp=pos,
                                                             lamp_diameter_m=lamp.diameter_m)[0])
    assert got[0.0, 4.0] == pytest.approx(got[0.0, 3.0], abs=1e-9)
    centre = np.asarray(cfg.target().center_enu_m, float)
    steps, _ = pose_batch.aim_steps(HeliostatKinematics.from_config(h), values[0], centre[None], lamp=pos)
    at_aim = predict_spots(HeliostatKinematics.from_config(h), MirrorOptics.from_config(h.mirror), values[0],
                           np.diag((0.1 * PRIOR_SIGMA_SI) ** 2), steps, centre[None], frame, lamp=pos,
                           lamp_diameter_m=lamp.diameter_m).position_sigma_m[0, 0]
    assert got[0.1, 4.0] - got[0.1, 3.0] >= 0.9 * at_aim > 0


def test_position_uncertainty_follows_the_covariance_and_distance(cfg):
    """σ_pos of Eq. (3): nil without uncertainty, proportional to the model's σ, larger for a
    heliostat farther away (a rotation moves the spot by 2 × distance)."""
    frame = TargetFrame.from_config(cfg.target(), (cfg.camera.height_px, cfg.camera.width_px))
    lamp = cfg.light_source()
    pos = np.asarray(lamp.position_enu_m, float)
    centre = np.asarray(cfg.target().center_enu_m, float)
    got = {}
    for hid in ("H04", "H13"):  # 40 m and 74 m from the tower
        h = cfg.heliostat(hid)
        kin = HeliostatKinematics.from_config(h)
        model = TrackingModel.zero()
        steps, ok = pose_batch.aim_steps(kin, model.values, centre[None], lamp=pos)
        assert ok[0]
        optics = MirrorOptics.from_config(h.mirror)
        for scale in (0.0, 1.0, 2.0):
            cov = np.diag((scale * PRIOR_SIGMA_SI) ** 2)
            sp = predict_spots(kin, optics, model.values, cov, steps, centre[None], frame, lamp=pos,
                               lamp_diameter_m=lamp.diameter_m)
            got[hid, scale] = sp
        assert got[hid, 0.0].position_sigma_m[0] == pytest.approx([0.0, 0.0], abs=1e-6)
        doubled = 2 * got[hid, 1.0].position_sigma_m[0]
        assert got[hid, 2.0].position_sigma_m[0] == pytest.approx(doubled, rel=1e-6)
        assert got[hid, 1.0].offset_m[0] == pytest.approx([0.0, 0.0], abs=1e-9)
    assert np.all(got["H13", 1.0].position_sigma_m[0] > 1.2 * got["H04", 1.0].position_sigma_m[0])


def test_measurable_spots_are_whole_in_the_simulated_plants_view(tmp_path):
    """Against the simulated plant's own optics (simplant.devices.cheap_camera draws each spot from the
    hidden heliostat's true beam, with its own spot model): on a field calibrated at night 0,
    every spot the planner calls measurable is drawn whole inside the camera's view, and the
    true centres fall within the predicted 3σ of the aim point as often as 3σ promises
    (the truth has effects no model term has: a few may fall outside)."""
    from controller.calibration.night.candidates import FieldGeometry, evaluate
    from controller.calibration.night.daytime import model_covariance
    from controller.calibration.night.planner import aim_points, planner_sun
    from controller.commands.cheap_night import calibrate_from_truth
    from controller.storage.db import CampaignStore
    from simplant.cheap_night import CheapField, field_data
    from simplant.devices.cheap_camera import SPOT_EXTENT_SIGMA
    from simplant.devices.cheap_camera import spot_covariance as true_spot

    base = yaml.safe_load((REPO / "configs" / "demo.yaml").read_text())
    field = CheapField(field_data(base, 30, 1, 3), tmp_path)
    calibrate_from_truth(field, "f")
    with CampaignStore(field.db_path, readonly=True) as store:
        models = store.latest_models()
    cfg = field.cfg
    geo = FieldGeometry(cfg, planner_sun(cfg), aim_points)
    view = geo.views["T1"]
    fr = view.frame
    within, count = 0, 0
    for h in cfg.heliostats:
        model, cov = model_covariance(models.get(h.id), cfg.calibration.model)
        c = evaluate(geo, h.id, model, cov, "T1")
        for k, (lamp, point, st) in enumerate(zip(c.lamps, c.points, c.steps, strict=True)):
            hit = field.true_hit(h.id, *st, lamp, "T1")
            c_true = field.plant.true_mirror_center(h.id, *st)
            beam = (hit - c_true) / np.linalg.norm(hit - c_true)
            source = cfg.light_source(lamp)
            angle = source.diameter_m / np.linalg.norm(np.asarray(source.position_enu_m, float) - c_true)
            m = h.mirror
            sig = np.sqrt(np.diag(true_spot(np.linalg.norm(hit - c_true), angle, 1e-3 * m.slope_error_mrad,
                                            m.width_m, m.height_m, m.focal_length_m, beam, fr.normal, fr.u,
                                            fr.v)))
            at = np.abs([(hit - fr.center) @ fr.u, (hit - fr.center) @ fr.v])
            assert np.all(at + SPOT_EXTENT_SIGMA * sig <= view.half_view_m), (h.id, lamp, at, sig)
            miss = np.abs([(hit - point) @ fr.u, (hit - point) @ fr.v])
            within += bool(np.all(miss <= 3.0 * c.spots.position_sigma_m[k]))
            count += 1
    assert count > 100
    assert within >= 0.95 * count


def test_a_lamps_spot_size_follows_the_ray_traced_mirror_at_the_lamps_distance():
    """Eq. (1) with the lamp focused at its own distance d against the simulated plant's ray
    tracer (second moments add under convolution, so σ² is the quantity to compare): a lamp
    55 m from a mirror focused at 50 m gives a spot nearly as wide as the mirror, which the
    far-source form (d = ∞) underestimates several-fold; at 300 m both come close."""
    from simplant.optics import MirrorSurface, TargetGrid, render_spot

    pos, aim = np.array([0.0, 50.0, 2.0]), np.array([0.0, 0.0, 30.0])
    normal, up = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
    u = np.cross(up, normal)
    grid = TargetGrid(aim, normal, u, np.cross(u, normal), 12.0, 12.0, (240, 240))
    mirror = MirrorSurface(3.2, 2.56, 50.0, 1.5)
    for lamp, far in (([0.0, 5.0, 55.0], False), ([0.0, -280.0, 120.0], True)):
        lamp = np.asarray(lamp, float)
        n = (lamp - pos) / np.linalg.norm(lamp - pos) + (aim - pos) / np.linalg.norm(aim - pos)
        img = render_spot(pos, n, lamp, 0.3 / np.linalg.norm(lamp - pos), mirror, grid, n_rays=60_000)
        rows, cols = np.indices(img.shape)
        w = img / img.sum()
        var = [float((w * (c - (w * c).sum()) ** 2).sum()) * (12.0 / 240) ** 2 for c in (cols, rows)]
        beam = (aim - pos) / np.linalg.norm(aim - pos)
        d = float(np.linalg.norm(lamp - pos))
        args = (float(np.linalg.norm(aim - pos)), 0.3 / d, 1.5e-3, 3.2, 2.56, 50.0, beam, N, U, V)
        at_d = np.diag(spot_covariance(*args, source_distance_m=d))
        at_inf = np.diag(spot_covariance(*args))
        print(f"lamp at {d:.0f} m: σ ray-traced {np.sqrt(var)} m, Eq. 1 {np.sqrt(at_d)} m, "
              f"d = ∞ {np.sqrt(at_inf)} m")
        assert np.allclose(at_d, var, rtol=0.15), (lamp, at_d, var)
        if not far:
            assert np.all(at_inf < 0.25 * np.asarray(var))  # the far-source form: several-fold too small
