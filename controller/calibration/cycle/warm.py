"""What a lamp change or a pass asks of thousands of heliostats' pointings, solved in batches
before they ask one at a time: their park clearances and the steps onto their aim and
standby points (:class:`controller.calibration.cycle.pointing.GeometryPointing`, which keeps
both, :mod:`controller.calibration.cycle.solved`). One at a time each costs about half a
millisecond (an aim solve) to a few (a clearance); a batch over a
:class:`controller.geometry.pose_batch.KinStack` a few microseconds a heliostat.

The slews a slot's check asks for (:func:`warm_slews`) are traced the same way: the poses of
H heliostats' slews through :func:`controller.geometry.pose_batch.normal_and_center` over a
:class:`KinStack`, the same reflection and the same target and person-zone tests per ray as
:meth:`BeamSafety.warm_paths` (the same slews kept, checked in tests/calibration/cycle/test_warm.py).

The batched aim solve (:func:`controller.geometry.pose_batch.aim_steps`) is the scalar one
(:func:`controller.geometry.model.tracking.model_aim`) over a stack: the same bisector from
the model's mirror centre, the lamp's direction taken from it, the same three passes — the
same steps (checked in tests/calibration/cycle/test_warm.py). Heliostats without a model aim
by the nominal kinematics, which take the lamp's direction from the pivot: they are left to
the scalar solve."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

import numpy as np

from controller.calibration.cycle.beam_safety import wait_depths_clear
from controller.calibration.cycle.pointing import _AIMS, _CLEARANCES, GeometryPointing, clearances
from controller.calibration.cycle.solved import source_key
from controller.errors import HeliocalError
from controller.geometry.model.tracking import TrackingModel
from controller.geometry.pose_batch import KinStack, aim_steps, normal_and_center

SLEW_BATCH = 64  # heliostats traced at once: 64 x 243 poses, a few MB per array


def warm_clearances(pointings: Iterable[GeometryPointing]) -> None:
    """The park clearances (:meth:`GeometryPointing.park_clearance_m`) of ``pointings`` not yet
    kept, for their own source and model, batched per source, view and model settings."""
    todo: dict[tuple, list] = {}
    for p in pointings:
        key = p._clearance_key(p.source, p.model)
        if _CLEARANCES.peek(key, (p.heliostat, p.model_settings)) is None:
            f = p.frame
            group = (source_key(p.source), f.center.tobytes(), f.u.tobytes(), f.width_m, id(p.model_settings))
            todo.setdefault(group, []).append((key, p))
    for items in todo.values():
        for (key, p), c in zip(items, clearances([(p, p.source, p.model) for _, p in items]), strict=True):
            _CLEARANCES.put(key, (p.heliostat, p.model_settings), float(c))


def warm_aims(pointings: Iterable[GeometryPointing], approaches: bool = False) -> None:
    """The steps onto the aim point and the standby points on both sides of ``pointings``
    with a model (for their own source and model), batched per source; their clearances first
    (:func:`warm_clearances`: the standby points depend on them); with ``approaches``, for a
    pass that will ask for their aims, their approaches through the person zones too
    (:func:`warm_approaches`)."""
    pointings = [p for p in pointings if p.model is not None]
    warm_clearances(pointings)
    todo: dict[tuple, list] = {}
    for p in pointings:
        points = [p.aim_point, *p.side_points()]
        if not np.isfinite(points).all():  # no park beside the view in reach: the scalar solve says so
            continue
        keys = [p._aim_key(x, p.model) for x in points]
        if any(_AIMS.peek(k, (p.heliostat,)) is None for k in keys):
            # A lamp's direction is taken from each mirror centre: one batch per lamp (keyed by
            # each heliostat's direction to it, every heliostat was a batch of its own).
            group = (p.source_pos,) if p.source_pos is not None else (p.source_dir.tobytes(),)
            todo.setdefault(group, []).append((p, np.array(points), keys))
    for items in todo.values():
        p0 = items[0][0]
        kin = KinStack.of([p.kin for p, _, _ in items])
        values = np.array([TrackingModel.from_dict(p.model.params).values for p, _, _ in items])
        points = np.array([x for _, x, _ in items])  # (H, 3, 3)
        lamp = None if p0.source_pos is None else np.asarray(p0.source_pos, float)
        dirs = None if lamp is not None else np.broadcast_to(p0.source_dir, points.shape)
        steps, ok = aim_steps(kin.shaped(2), values[:, None, :], points, lamp=lamp, source_dirs=dirs)
        for (p, _, keys), st, fine in zip(items, steps, ok, strict=True):
            for key, s, f in zip(keys, st, fine, strict=True):
                if f:  # out of reach: the scalar solve says so, naming the axis
                    _AIMS.put(key, (p.heliostat,), (int(s[0]), int(s[1])))
    if approaches:
        warm_approaches(pointings)


def warm_slews(items: Iterable[tuple[GeometryPointing, Sequence]]) -> None:
    """The direct slews to standby from each of the poses (or None) of ``items`` ((pointing,
    poses)) with a model: traced in batches (per source, targets and person zones) and kept for
    :meth:`BeamSafety.path_to` as :meth:`BeamSafety.warm_paths` keeps them — a pass's slot checks
    (:func:`controller.calibration.beams.group.slot_parks`) ask for the slews from where each
    heliostat stands, from its aim and from its identity-stepped pose. A pointing out of reach
    is left to its check, which says why."""
    todo = []
    for p, starts in items:
        if p.model is None:
            continue
        try:
            end = p.standby_steps(p.model)
        except (HeliocalError, ValueError):
            continue
        slews, poses = p.direct_slews(starts, end)
        if slews:
            todo.append((p, end, slews, poses))
    in_batches(todo, _trace_slews)


def _trace_slews(items: list) -> None:
    ps = [p for p, _, _, _ in items]
    c, b, m = batch_rays(ps, [np.vstack(poses) for _, _, _, poses in items])
    margins = np.repeat([np.broadcast_to(p.path_margin_m(), (2,)) for p in ps], m, axis=0)
    inside = ps[0]._inside(c, b, margins).reshape(len(ps), m, -1)
    for (p, end, starts, poses), rays in zip(items, inside, strict=True):
        p.keep_clear(starts, end, poses, rays)


def warm_approaches(pointings: Iterable[GeometryPointing]) -> None:
    """The approaches from standby to the aim of ``pointings`` with a model, where the plant has
    person zones: traced through the zones in batches (per source, targets and zones), and the
    aim kept for :meth:`GeometryPointing.aim_steps` where no pose of the approach enters one —
    what aim_steps checks before it answers. One that enters a zone, or is out of reach, is
    left to aim_steps, which names the zone or the axis."""
    items = []
    for p in pointings:
        key = ("aim", p._aim_key(p.aim_point, p.model))
        if p.model is None or not p.zone_ids or p._with_model(key) in p._poses:
            continue
        try:
            aim = p._steps(p.aim_point, p.model)
            items.append((p, key, aim, p._sweep(p.standby_steps(p.model), aim)))
        except (HeliocalError, ValueError):
            continue
    in_batches(items, _trace_approaches)


def _trace_approaches(items: list) -> None:
    ps = [p for p, _, _, _ in items]
    c, b, m = batch_rays(ps, [sweep for _, _, _, sweep in items])
    inside = ps[0]._in_zone(c, b).reshape(len(ps), m)
    for (p, key, aim, sweep), entered in zip(items, inside, strict=True):
        if not entered[:len(sweep)].any():
            p._kept(key, lambda aim=aim: aim)


def warm_waits(pointings: Iterable[GeometryPointing], current: Mapping[str, tuple[int, int]]) -> None:
    """Whether each of ``pointings`` with a model may wait where it stands (``current``, by id)
    rather than park first (:meth:`BeamSafety.may_wait_at`, what its cycle asks as it prepares):
    the rays at its pose and standby and along its approach traced in batches, and the answer
    kept as may_wait_at keeps it, from the same tests of the same rays."""
    items = []
    for p in pointings:
        pose = current.get(p.heliostat.id)
        if p.model is None or pose is None:
            continue
        try:
            aim, standby = p.aim_steps(p.model), p.standby_steps(p.model)
        except (HeliocalError, ValueError):
            continue
        key = p.wait_key(pose, standby, aim, p.path_margin_m())
        if key not in p._waits and p.wait_worth_checking(pose, standby, aim):
            items.append((p, key, np.array([pose, standby], float), p._sweep(pose, aim)))
    in_batches(items, _trace_waits)


def _trace_waits(items: list) -> None:
    ps = [p for p, _, _, _ in items]
    first = ps[0]
    c, b, _ = batch_rays(ps, [here for _, _, here, _ in items])
    margins = np.repeat([np.broadcast_to(p.path_margin_m(), (2,)) for p in ps], 2, axis=0)
    depths = first._depths(c, b, margins).reshape(len(ps), 2, 2)
    zones = first._in_zone(c, b).reshape(len(ps), 2)
    c, b, m = batch_rays(ps, [sweep for _, _, _, sweep in items])
    crossed = (first._on_others(c, b, 2.0) | first._in_zone(c, b)).reshape(len(ps), m)
    for (p, key, _, sweep), depth, zone, cross in zip(items, depths, zones, crossed, strict=True):
        p._waits[key] = wait_depths_clear(depth, bool(zone[0])) and not cross[:len(sweep)].any()


def in_batches(items: list, trace) -> None:
    """``trace`` the ``items`` (pointing first) in batches of :data:`SLEW_BATCH` that share what
    a ray's tests need: the source, the targets and the person zones."""
    groups: dict[tuple, list] = {}
    for it in items:
        p = it[0]
        key = (p.lamp.tobytes() if p.lamp is not None else p.source_dir.tobytes(),
               *(a.tobytes() for a in p._planes), p.zones.tobytes())
        groups.setdefault(key, []).append(it)
    for group in groups.values():
        for k in range(0, len(group), SLEW_BATCH):
            trace(group[k:k + SLEW_BATCH])


def batch_rays(pointings: list[GeometryPointing],
               poses: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, int]:
    """Mirror centres and reflected beams (H·M, 3) of each pointing's ``poses`` (M_i, 2) through its
    ray model (:meth:`BeamSafety.rays`, H heliostats at once), each padded to the longest (M)
    with its last pose: (centres, beams, M)."""
    m = max(len(x) for x in poses)
    steps = np.array([np.vstack([x, np.repeat(x[-1:], m - len(x), axis=0)]) for x in poses])  # (H, M, 2)
    values = np.array([p.ray_model for p in pointings])[:, None, :]
    n, c = normal_and_center(KinStack.of([p.kin for p in pointings]).shaped(2), values, steps)
    n, c = n.reshape(-1, 3), c.reshape(-1, 3)
    return c, pointings[0].reflected(n, c), m
