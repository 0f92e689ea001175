"""Campaign geometry glue: camera frame mapping, slew times, beam-safe paths to standby."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from controller.calibration.campaign.queue_order import order_queue, slew_time_s
from controller.calibration.cycle.beam_safety import WAIT_SLOWER_S, UnsafePath
from controller.calibration.cycle.pointing import GeometryPointing
from controller.calibration.records import ModelRecord
from controller.config import load_config
from controller.geometry.target_frame import TargetFrame
from simplant.optics import TargetGrid


@pytest.fixture(scope="module")
def cfg():
    return load_config(Path(__file__).resolve().parents[3] / "configs" / "demo.yaml")


def test_frame_corners_by_hand(cfg):
    # 8 m x 7 m north-facing target at (0, 0, 30), 1024 x 768 camera: pitch = max(8/1024, 7/768)
    f = TargetFrame.from_config(cfg.target(), (768, 1024))
    p = 7.0 / 768
    assert f.width_m == pytest.approx(1024 * p) and f.height_m == pytest.approx(7.0)
    # u = up x n = west, v = u x n = down: the outer corner of pixel (0, 0) is east and up
    np.testing.assert_allclose(f.pixel_to_enu(-0.5, -0.5), [1024 * p / 2, 0.0, 33.5], atol=1e-12)
    np.testing.assert_allclose(f.pixel_to_enu(1023.5, 767.5), [-1024 * p / 2, 0.0, 26.5], atol=1e-12)
    np.testing.assert_allclose(f.pixel_to_enu(511.5, 383.5), [0.0, 0.0, 30.0], atol=1e-12)


def test_frame_agrees_with_the_simulators_grid(cfg):
    f = TargetFrame.from_config(cfg.target(), (192, 256))
    g = TargetGrid(f.center, f.normal, f.u, f.v, f.width_m, f.height_m, f.shape)
    rng = np.random.default_rng(0)
    for x, y in rng.uniform(-0.5, 255.5, (20, 2)):
        np.testing.assert_allclose(f.pixel_to_enu(x, y), g.pixel_to_enu(x, y), atol=1e-12)


@pytest.mark.parametrize(
    "steps, expected", [(10000, 10000 / 1540 + 1540 / 3000), (100, 2 * (100 / 3000) ** 0.5), (0, 0.0)]
)
def test_slew_time(steps, expected):
    # trapezoid: d/v + v/a above the ramp distance v^2/a = 790.5 steps, else triangle 2 sqrt(d/a)
    assert slew_time_s(steps, 1540.0, 3000.0) == pytest.approx(expected)


def _pointing(cfg, hid, current):
    return GeometryPointing(
        cfg.heliostat(hid),
        cfg.target(),
        cfg.light_source(),
        TargetFrame.from_config(cfg.target(), (768, 1024)),
        8.0,
        current,
    )


@pytest.mark.parametrize("hid", ["H01", "H04", "H10", "H16"])
def test_path_from_stow_never_crosses_the_target(cfg, hid):
    p = _pointing(cfg, hid, (500, 500))
    standby = p.standby_steps(None)
    assert not p.beam_on_target(*standby, margin_m=0.0)
    assert p.beam_on_target(*p.aim_steps(None), margin_m=0.0)
    path = p.path_to((500, 500), standby)
    assert path[-1] == standby
    assert p.path_to(standby, standby) == []  # parked already: nothing to move
    # independent check: sample every leg with each axis at its own speed
    pts, start = [], np.array([500.0, 500.0])
    for wp in path:
        end = np.array(wp, float)
        dur = np.abs(end - start) / 1540.0
        for t in np.linspace(0, dur.max(), 400):
            pts.append(start + np.minimum(1, t / np.maximum(dur, 1e-12)) * (end - start))
        start = end
    assert not any(p.beam_on_target(*q, margin_m=0.0) for q in pts)


def _slew_s(p, start, end) -> float:
    """Seconds of a slew, each axis at its configured speed (independent of ``BeamSafety._slew_s``)."""
    ax = p.heliostat.axes
    return max(abs(end[0] - start[0]) / ax.azimuth.speed_steps_per_s,
               abs(end[1] - start[1]) / ax.elevation.speed_steps_per_s)


def test_a_heliostat_parked_beside_the_target_waits_there_instead_of_sliding_along_the_view(cfg):
    """Parked beside the target (a lamp change's standby, higher or lower than its own) and about
    to be measured: it waits there (``may_wait_at``) when its beam there is off the target by the
    path margin (as far out as a park) and its approach from there is at most ``WAIT_SLOWER_S``
    slower than from its standby: a slew between the two would slide the spot along the view's
    edge while other beams are measured. A beam inside the margin moves, even one outside the
    view margin (a whole plan had 152 foreign captures from such waits); so does one parked so
    far off that its approach would keep the target waiting."""
    waits = slower = betweens = 0
    fitted = ModelRecord({"az_offset_mrad": 0.5}, {}, 0.0, 1)  # the prior's σ: margins beyond 2 m
    for h, model in itertools.product(cfg.heliostats, (None, fitted)):
        p = GeometryPointing(cfg.heliostat(h.id), cfg.target(), cfg.light_source(),
                             TargetFrame.from_config(cfg.target(), (768, 1024)), 8.0, None, model=model)
        f, aim = p.frame, p.aim_steps(model)
        m = p.path_margin_m()
        mu = float(np.broadcast_to(m, (2,))[0])
        slack = mu - float(np.broadcast_to(p.view_margin_m(), (2,))[0])  # 0 where both are 2 m
        out = max(p.park_clearance_m(p.source, None), p.target.width_m / 2 + mu) + 1.0
        for side in (1.0, -1.0):
            standby = p.kin.aim(p.source_dir, f.center + side * out * f.u)
            for dv in (-6.0, -3.0, 3.0, 6.0, 40.0):
                a = p.kin.aim(p.source_dir, f.center + side * out * f.u + dv * f.v)
                assert not p.on_target([a], margin_m=m).any()
                if _slew_s(p, a, aim) <= _slew_s(p, standby, aim) + WAIT_SLOWER_S - 0.05:
                    assert p.may_wait_at(a, standby, aim, m), (h.id, side, dv)
                    waits += 1
                elif _slew_s(p, a, aim) > _slew_s(p, standby, aim) + WAIT_SLOWER_S + 0.05:
                    assert not p.may_wait_at(a, standby, aim, m), (h.id, side, dv)
                    slower += 1
            inside = p.kin.aim(p.source_dir, f.center + side * (p.target.width_m / 2 + mu - 1.0) * f.u)
            assert p.on_target([inside], margin_m=m).any()
            assert not p.may_wait_at(inside, standby, aim, m)
            if slack > 0.2:
                u = p.target.width_m / 2 + mu - slack / 2
                between = p.kin.aim(p.source_dir, f.center + side * u * f.u)
                assert not p.on_target([between], margin_m=p.view_margin_m()).any()
                assert not p.may_wait_at(between, standby, aim, m)  # out of the view, not as a park
                betweens += 1
            assert not p.may_wait_at(standby, standby, aim, m)  # nothing to wait for
    assert waits and slower and betweens  # all arise on the demo field


def test_path_across_the_target_is_refused(cfg):
    p = _pointing(cfg, "H04", None)
    west = p.kin.aim(p.source_dir, p.aim_point + 8.0 * np.array([-1.0, 0.0, 0.0]))
    east = p.kin.aim(p.source_dir, p.aim_point + 8.0 * np.array([1.0, 0.0, 0.0]))
    with pytest.raises(UnsafePath, match="off the target"):
        p.path_to(west, east)


@pytest.fixture(scope="module")
def wide(cfg):
    """A 300-heliostat field of the 10,000-field's kind (simplant.cheap_night, K = 4): targets
    sized for the far rows' spots, a camera view reaching beyond each side of its target."""
    import yaml

    from controller.config import parse_config
    from simplant.cheap_night import field_data

    base = yaml.safe_load((Path(__file__).resolve().parents[3] / "configs" / "demo.yaml").read_text())
    return parse_config(field_data(base, 300, 1, 1, beams=4), "wide.yaml")


def test_a_slew_keeps_its_spot_out_of_the_view_not_only_its_ray_off_the_target(wide):
    """Issue 42: a slew beside the target whose central ray stayed 2 m off it put the spot's
    tails into the camera's view (which reaches beyond the target) while other beams were
    measured there. The margin is the spot's footprint beyond the view. From below the target to
    above it along the side of the view, just inside the margin and just beyond it: a path is
    refused, or its whole sweep keeps out of the margin (wider than the old 2 m)."""
    from tests.calibration.conftest import calibrated_record

    cam, t = wide.camera, wide.target()
    f = TargetFrame.from_config(t, (cam.height_px, cam.width_px))
    excess = np.array([f.width_m - t.width_m, f.height_m - t.height_m]) / 2
    for hid in ("F0001", "F0100", "F0200", "F0300"):
        model = calibrated_record(wide, hid)
        p = GeometryPointing(wide.heliostat(hid), t, wide.light_source(), f, 12.0, None, model=model)
        size, position = p.spot_sigmas_m(p.source, model)
        margin = p.path_margin_m()
        foot = np.maximum(2.0, 3.0 * (size + position) + 0.5 + excess)
        park = p.park_clearance_m(p.source, model) - t.width_m / 2  # beside the view: sized where it parks
        np.testing.assert_allclose(margin, [max(foot[0], park - 0.1), foot[1]])
        assert margin[0] > 2.5 and excess[0] > 0.5  # the view's side and the spot count
        below, above = -(t.height_m / 2 + margin[1] + 1.0), t.height_m / 2 + margin[1] + 1.0
        for u in (t.width_m / 2 + margin[0] - 0.5, t.width_m / 2 + margin[0] + 0.5):
            start = p._steps(f.center + u * f.u + below * f.v, model)  # the model its rays are traced with
            end = p._steps(f.center + u * f.u + above * f.v, model)
            assert not p.on_target([start, end], margin_m=margin).any()  # both ends out of the margin
            through = p.on_target(p._sweep(start, end), margin_m=margin).any()
            try:
                path = p.path_to(start, end)
            except UnsafePath:
                assert through
                continue
            assert path[-1] == end and (path != [end] or not through)
            sweep = np.vstack([p._sweep(a, b) for a, b in zip([start, *path[:-1]], path, strict=True)])
            assert not p.on_target(sweep, margin_m=margin).any()


def test_queue_shortest_slew_first(cfg):
    ids = ["H01", "H02", "H03"]
    pts = {h: _pointing(cfg, h, (500, 500)) for h in ids}
    current = {h: pts[h].standby_steps(None) for h in ids}
    current["H02"] = (500, 500)  # far away: goes last
    assert order_queue(cfg, ids, current, pts)[-1] == "H02"


def test_with_several_beams_the_queue_groups_like_slews_and_ends_with_the_quickest(cfg):
    ids = [h.id for h in cfg.heliostats]
    pts = {h: _pointing(cfg, h, (500, 500)) for h in ids}
    current = {h: (500 + 40 * i, 500) for i, h in enumerate(ids)}
    one, four = order_queue(cfg, ids, current, pts), order_queue(cfg, ids, current, pts, beams=4)
    assert sorted(four) == sorted(ids) and four[:4] == one[:4]  # the first round: the first at standby

    def onto_target(hid):  # standby to aim point, the slower axis (trapezoid, as test_slew_time)
        p, ax = pts[hid], cfg.heliostat(hid).axes
        d = np.abs(np.subtract(p.aim_steps(None), p.standby_steps(None)))
        return max(slew_time_s(d[0], ax.azimuth.speed_steps_per_s, ax.azimuth.acceleration_steps_per_s2),
                   slew_time_s(d[1], ax.elevation.speed_steps_per_s, ax.elevation.acceleration_steps_per_s2))

    rest = [onto_target(h) for h in four[4:]]
    assert rest == sorted(rest, reverse=True) and rest[0] > rest[-1]
    # A heliostat measured alone earlier tonight goes last, where a pass's lone beam is.
    late = order_queue(cfg, ids, current, pts, beams=4, last=(four[1],))
    assert late[-1] == four[1] and late[:-1] == [h for h in four if h != four[1]]


def test_beam_chain_matches_with_a_multi_threshold_library(small_config):
    """The default ``library build`` features (``multi-hu``) need Hu moments at several
    thresholds: the chain's observation carries what its library matches on."""
    from controller.calibration.cycle.beam_chain import BeamChain
    from controller.config import load_config
    from controller.recognition.library import build_library

    cfg = load_config(small_config)
    rows, cols = cfg.camera.height_px, cfg.camera.width_px
    yy, xx = np.mgrid[0:rows, 0:cols]

    def spot(x0, y0, sx, sy):
        return 1000.0 * np.exp(-((xx - x0) ** 2 / (2 * sx**2) + (yy - y0) ** 2 / (2 * sy**2)))

    images = [spot(120, 90, 9, 9), spot(130, 95, 14, 6), spot(110, 100, 6, 14)]
    lib = build_library(images, ["round", "wide", "tall"], kind="multi-hu")
    chain = BeamChain(cfg, lib)
    obs = chain.analyze(spot(125, 92, 13, 6) + 1.0)
    assert obs.hu.size == 7 * len(lib.thresholds) > 7
    m = chain.match(obs)
    assert m is not None and m.label == "wide"


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_a_beam_measured_beside_the_centre_parks_on_that_side(cfg, side):
    """Several beams per target: a heliostat measured at a slot off the centre parks on the
    slot's side, whichever side it waited on, its park clearance from the centre (at least the
    configured offset from the slot): nearer the slot than the other side's standby."""
    from controller.geometry.spot import hit_uv

    frame = TargetFrame.from_config(cfg.target(), (768, 1024))
    aim = np.asarray(cfg.target().center_enu_m, float) + side * 2.0 * frame.u
    h, target, lamp = cfg.heliostat("H04"), cfg.target(), cfg.light_source()
    p = GeometryPointing(h, target, lamp, frame, 8.0, None, aim_point=aim)
    leave = p.leave_steps(None)
    c, b = p.rays([leave])
    u, _ = hit_uv(c, b, frame.center, frame.normal, frame.u, frame.v)[0]
    assert u == pytest.approx(side * max(p.park_clearance_m(lamp, None), 2.0 + 8.0), abs=0.05)
    far = [q for q in p.side_points() if float((q - frame.center) @ frame.u) * side < 0][0]
    assert abs(u - 2.0 * side) < abs(float((far - aim) @ frame.u)) == pytest.approx(p.standby_offset_m)
    assert not p.beam_on_target(*leave, margin_m=0.0)
    assert p.path_to(p.aim_steps(None), leave)[-1] == leave  # off the target the short way, never back
    centre = GeometryPointing(h, target, lamp, frame, 8.0, None)
    assert centre.leave_steps(None) == centre.standby_steps(None)  # on the centre line: its standby


def test_a_round_member_parks_with_the_model_refitted_on_its_measurement(cfg):
    """After a shared capture the heliostat leaves for its slot's side with the model its run
    just refitted (it has seen where the beam went), not the one it came with; a run without a
    new model leaves with the old one."""
    from types import SimpleNamespace

    from controller.calibration.cycle.park import leave_pose
    from tests.calibration.conftest import calibrated_record

    frame = TargetFrame.from_config(cfg.target(), (768, 1024))
    aim = np.asarray(cfg.target().center_enu_m, float) + 2.0 * frame.u
    old = calibrated_record(cfg, "H04")
    shifted = {**old.params, "el_offset_mrad": old.params["el_offset_mrad"] + 2.0}
    new = ModelRecord(shifted, {}, 0.2, 4, old.detail)
    p = GeometryPointing(cfg.heliostat("H04"), cfg.target(), cfg.light_source(), frame, 8.0, None,
                         aim_point=aim, model=old)
    at = p.aim_steps(old)

    def cycle(refit, measurements=()):
        return SimpleNamespace(ctx=SimpleNamespace(pointing=p, model=old), at=at,
                               standby=p.standby_steps(old),
                               run_rec=SimpleNamespace(model=refit, measurements=list(measurements)))

    assert p.leave_steps(new) != p.leave_steps(old)
    assert leave_pose(cycle(new)) == p.leave_steps(new)
    assert leave_pose(cycle(None)) == p.leave_steps(old)
    seen = SimpleNamespace(az_steps=at[0], el_steps=at[1], centroid_enu=tuple(p.aim_point + 0.4 * frame.v))
    assert leave_pose(cycle(new, [seen])) == p.leave_steps(new, (at, seen.centroid_enu))


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_a_beam_seen_away_from_where_its_model_puts_it_parks_that_much_farther_out(cfg, side):
    """The park after a measurement lies as much farther from the view as the measured centroid
    lay from where the refitted model puts that pose's beam (a model that could not follow its
    measurements, or a centroid off: either way the parked spot clears the view); a centroid where
    the model puts the beam leaves the park where it was."""
    from controller.geometry.model.tracking import TrackingModel
    from tests.calibration.conftest import calibrated_record

    frame = TargetFrame.from_config(cfg.target(), (768, 1024))
    model = calibrated_record(cfg, "H04")
    p = GeometryPointing(cfg.heliostat("H04"), cfg.target(), cfg.light_source(), frame, 8.0, None,
                         aim_point=np.asarray(cfg.target().center_enu_m, float) + side * 2.0 * frame.u,
                         model=model)
    pose = p.aim_steps(model)
    values = TrackingModel.from_dict(model.params).values
    u0, v0 = p.plane_uv([pose], values)[0]
    assert abs(u0 - side * 2.0) < 0.01 and abs(v0) < 0.01  # the model puts the beam on its aim

    def parked_u(seen_uv) -> float:
        centroid = frame.center + seen_uv[0] * frame.u + seen_uv[1] * frame.v
        return float(p.plane_uv([p.leave_steps(model, (pose, centroid))], values)[0, 0])

    base = float(p.plane_uv([p.leave_steps(model)], values)[0, 0])
    assert np.sign(base) == side and abs(base) > frame.width_m / 2
    assert parked_u((u0, v0)) == pytest.approx(base, abs=0.01)
    for du, dv in ((0.3, 0.4), (-0.6, 0.8), (0.0, -1.5)):  # d = 0.5, 1.0, 1.5 m, towards either side
        d = float(np.hypot(du, dv))
        assert parked_u((u0 + du, v0 + dv)) == pytest.approx(base + side * d, abs=0.02)


def test_aim_and_standby_steps_are_traced_once_per_model_and_ray_model(cfg, monkeypatch):
    """A pointing keeps its aim and standby steps (each traced through the person zones): asked
    again with the same model it traces nothing; another model, or another model for its rays
    (a search's fit), is traced again; the answers are those of a fresh pointing."""
    p = _pointing(cfg, "H04", None)
    traced = []
    real = p.in_zone
    monkeypatch.setattr(p, "zone_ids", ["z"])  # traced as if the plant had a zone
    monkeypatch.setattr(p, "in_zone", lambda poses: traced.append(len(poses)) or real(poses))
    monkeypatch.setattr(p, "beam_in_zone", lambda az, el: traced.append(1) and None)
    first = p.aim_steps(None), p.standby_steps(None)
    n = len(traced)
    assert n and (p.aim_steps(None), p.standby_steps(None)) == first and len(traced) == n
    model = ModelRecord({"az_offset_mrad": 0.5}, {}, 0.0, 1)
    assert p.aim_steps(model) != first[0] and len(traced) > n
    n = len(traced)
    p.ray_model = p.ray_model + 1e-4
    p.aim_steps(model)
    assert len(traced) > n
    fresh = _pointing(cfg, "H04", None)
    assert (fresh.aim_steps(None), fresh.standby_steps(None)) == first



@pytest.mark.parametrize("lamp", ["lamp-low", "lamp-west", "lamp-tower-mid"])
def test_the_ray_checked_under_a_lamp_lands_where_the_pose_was_solved_to(cfg, lamp):
    """The beam-safety ray at a pose solved for a point (the standby) lands on that point: the lamp's
    light is taken from the lamp to the pose's mirror centre, as the solution takes it — with a
    model whose pivot is 0.3 m off the survey the nominal position's direction missed by decimetres
    (a standby solved just outside a path's margin was traced inside it: issue 42)."""
    model = ModelRecord({"position_e_mm": 300.0, "position_u_mm": -300.0, "az_offset_mrad": 2.0}, {}, 0.0, 5)
    frame = TargetFrame.from_config(cfg.target(), (768, 1024))
    worst = 0.0
    for h in cfg.heliostats:
        p = GeometryPointing(h, cfg.target(), cfg.light_source(lamp), frame, 8.0, None, model=model)
        c, b = p.rays([p.standby_steps(model)])
        t = ((frame.center - c[0]) @ frame.normal) / (b[0] @ frame.normal)
        worst = max(worst, float(np.linalg.norm(c[0] + t * b[0] - p.standby_point)))
    assert worst < 0.05  # m: steps are whole (a step moves the spot about a centimetre)


def test_a_heliostat_whose_standby_lies_inside_the_margin_waits_no_deeper_than_its_standby(cfg):
    """A standby inside the path's margin (a far heliostat's footprint at the aim reaches beyond
    its park clearance): a pose beside it, higher or lower at the same distance from the view,
    may be waited at (a slew from there would start inside the margin and slide along it); a pose
    half a metre closer to the view may not."""
    frame = TargetFrame.from_config(cfg.target(), (768, 1024))
    waits = 0
    for h in cfg.heliostats:
        p = GeometryPointing(h, cfg.target(), cfg.light_source(), frame, 8.0, None)
        aim, standby, sp = p.aim_steps(None), p.standby_steps(None), p.standby_point
        side = np.sign(float((sp - frame.center) @ frame.u))
        u_in = float((sp - frame.center) @ frame.u) * side - p.target.width_m / 2  # m beyond the edge
        m = np.array([u_in + 1.0, 2.0])  # the standby 1 m inside the margin
        for dv in (-1.0, 1.0):
            beside = p.kin.aim(p.source_dir, sp + dv * frame.v)
            closer = p.kin.aim(p.source_dir, sp + dv * frame.v - 0.5 * side * frame.u)
            if _slew_s(p, beside, aim) <= _slew_s(p, standby, aim) + WAIT_SLOWER_S - 0.05:
                assert p.may_wait_at(beside, standby, aim, m), (h.id, dv)
                waits += 1
            assert not p.may_wait_at(closer, standby, aim, m), (h.id, dv)
    assert waits


def test_slews_traced_together_are_the_slews_traced_one_at_a_time(wide):
    """A slot's check traces a heliostat's three slews to standby in one evaluation
    (``warm_paths``): each answer is the one ``path_to`` gives alone — the same waypoints, or
    the same refusal — whether its direct slew is clear, needs a detour or has none."""
    from tests.calibration.conftest import calibrated_record

    cam, t = wide.camera, wide.target()
    f = TargetFrame.from_config(t, (cam.height_px, cam.width_px))
    kinds = set()
    for hid in ("F0001", "F0150", "F0300"):
        model = calibrated_record(wide, hid)
        h, lamp = wide.heliostat(hid), wide.light_source()
        alone, together = (GeometryPointing(h, t, lamp, f, 12.0, None, model=model) for _ in range(2))
        standby, aim = alone.standby_steps(model), alone.aim_steps(model)
        far = alone._steps(f.center - 3.0 * (alone.standby_point - f.center), model)  # across the target
        starts = [aim, far, (aim[0], far[1]), standby, None, aim]
        together.warm_paths(starts, standby)
        for s in (s for s in starts if s is not None):
            try:
                want = alone.path_to(s, standby)
            except UnsafePath as exc:
                with pytest.raises(UnsafePath, match=str(exc).split(":")[0]):
                    together.path_to(s, standby)
                kinds.add("refused")
                continue
            assert together.path_to(s, standby) == want
            kinds.add("direct" if want == [standby] else "detour" if want else "there")
    assert {"direct", "there"} <= kinds and kinds & {"detour", "refused"}


def test_a_model_that_could_not_follow_its_measurements_parks_farther_out(cfg):
    """A fit whose residual exceeds the stated noise holds effects its covariance does not (a
    measurement it could not follow, or a term it lacks): its park allows 3σ of that unexplained
    residual, doubled by the reflection, at the park's range; a fit within its noise parks where
    its covariance alone puts it."""
    from controller.calibration.cycle.model_update import unexplained_sigma_m
    from controller.geometry.model.tracking import TERMS
    from tests.calibration.conftest import calibrated_record

    frame = TargetFrame.from_config(cfg.target(), (768, 1024))
    base = calibrated_record(cfg, "H04")
    tight = {"covariance_si": (1e-14 * np.eye(len(TERMS))).tolist()}  # the position known to µrad

    def clearance(residual_mrad):
        model = ModelRecord(base.params, {}, residual_mrad, 6, tight)
        p = GeometryPointing(cfg.heliostat("H04"), cfg.target(), cfg.light_source(), frame, 8.0, None,
                             cfg.calibration.model, model=model)
        return p.park_clearance_m(p.source, model), p

    noise = cfg.calibration.model.noise_mrad
    within, _ = clearance(noise)
    assert clearance(0.5 * noise)[0] == within
    for r in (1.0, 3.0):
        c, p = clearance(r)
        throw = float(np.linalg.norm(frame.center - p.heliostat_pos))
        floor = unexplained_sigma_m(p.model, noise, frame.center - p.heliostat_pos)
        assert floor == pytest.approx(2e-3 * np.sqrt(r * r - noise * noise) * throw)
        # It replaces the covariance's 4σ position (here the stated noise's alone, at the park's
        # slightly longer throw) at 3σ: what it adds is 3 floor less that.
        assert 3.0 * floor - 4.0 * 1.2 * 2e-3 * noise * throw < c - within <= 3.0 * floor
