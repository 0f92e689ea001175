"""What a lamp change or a pass asks of thousands of heliostats' pointings, solved in batches
before they ask one at a time: their park clearances and the steps onto their aim and
standby points (:class:`controller.calibration.cycle.pointing.GeometryPointing`, which keeps
both, :mod:`controller.calibration.cycle.solved`). One at a time each costs about half a
millisecond (an aim solve) to a few (a clearance); a batch over a
:class:`controller.geometry.pose_batch.KinStack` a few microseconds a heliostat.

The slews a slot's check asks for (:func:`warm_slews`), and each aim's approach from standby
through the person zones (:func:`warm_approaches`), are traced the same way: the poses of
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

from collections.abc import Iterable, Mapping

import numpy as np

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
    (:func:`warm_clearances`: the standby points depend on them); with ``approaches``, then the
    approaches from standby to the aim through the person zones (:func:`warm_approaches`: a
    pass asks for every aim, a lamp change for none)."""
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


def warm_approaches(pointings: Iterable[GeometryPointing]) -> None:
    """The approaches from standby to the aim point of ``pointings`` with a model and person
    zones, as :meth:`GeometryPointing.aim_steps` traces them through the zones: in batches (per
    source, targets and person zones, as :func:`warm_slews`), each approach that enters no zone
    kept as the aim's steps; one that does, or a pointing out of reach, is left to
    ``aim_steps``, which says why. Its aim and standby steps first (:func:`warm_aims`)."""
    todo: dict[tuple, list] = {}
    for p in pointings:
        if p.model is None or not p.zone_ids:
            continue
        key = ("aim", p._aim_key(p.aim_point, p.model))
        if p._with_model(key) in p._poses:
            continue
        try:
            aim = p._steps(p.aim_point, p.model)
            sweep = p._sweep(p.standby_steps(p.model), aim)
        except (HeliocalError, ValueError):
            continue
        todo.setdefault(_ray_group(p), []).append((p, key, aim, sweep))
    for items in todo.values():
        for k in range(0, len(items), SLEW_BATCH):
            chunk = items[k:k + SLEW_BATCH]
            inside = _trace_zones([p for p, _, _, _ in chunk], [sweep for _, _, _, sweep in chunk])
            for (p, key, aim, _), entered in zip(chunk, inside, strict=True):
                if not entered.any():
                    p.kept(key, lambda a=aim: a)


def _ray_group(p: GeometryPointing) -> tuple:
    """What pointings traced in one batch share: the source (a lamp's position, or the sun's
    direction), the targets' planes and the person zones."""
    return (p.lamp.tobytes() if p.lamp is not None else p.source_dir.tobytes(),
            *(a.tobytes() for a in p._planes), p.zones.tobytes())


def _batch_rays(pointings: list[GeometryPointing], sweeps: list[np.ndarray]
                ) -> tuple[np.ndarray, np.ndarray, int]:
    """The rays of each of ``sweeps`` (poses, 2) of ``pointings`` sharing a :func:`_ray_group`, as
    :meth:`BeamSafety.rays` traces them: mirror centres and reflected beams (H · M, 3), each sweep
    padded to the longest (M poses) with its last pose, and M."""
    m = max(len(s) for s in sweeps)
    steps = np.array([np.vstack([s, np.repeat(s[-1:], m - len(s), axis=0)]) for s in sweeps])  # (H, M, 2)
    values = np.array([p.ray_model for p in pointings])[:, None, :]
    n, c = normal_and_center(KinStack.of([p.kin for p in pointings]).shaped(2), values, steps)
    n, c = n.reshape(-1, 3), c.reshape(-1, 3)
    return c, pointings[0].reflected(n, c), m


def _trace_zones(pointings: list[GeometryPointing], sweeps: list[np.ndarray]) -> np.ndarray:
    """Whether each ray of each of ``sweeps`` (poses, 2) enters a person zone (H, M), as
    :meth:`BeamSafety.in_zone` traces it (:func:`_batch_rays`)."""
    c, b, m = _batch_rays(pointings, sweeps)
    return pointings[0]._in_zone(c, b).reshape(len(pointings), m)


def warm_slews(pointings: Iterable[GeometryPointing], current: Mapping[str, tuple[int, int]]) -> None:
    """The direct slews to standby, from where each heliostat stands (``current``, by id) and from
    its aim, of ``pointings`` with a model: traced in batches (per source, targets and person
    zones) and kept for :meth:`BeamSafety.path_to` as :meth:`BeamSafety.warm_paths` keeps them. A
    pass's slot checks (:func:`controller.calibration.beams.group.slot_parks`) then trace only
    the slew from each identity-stepped pose. A pointing out of reach is left to its check, which
    says why."""
    todo: dict[tuple, list] = {}
    for p in pointings:
        if p.model is None:
            continue
        try:
            end = p.standby_steps(p.model)
            starts, poses = p.direct_slews((current.get(p.heliostat.id), p.aim_steps(p.model)), end)
        except (HeliocalError, ValueError):
            continue
        if starts:
            todo.setdefault(_ray_group(p), []).append((p, end, starts, poses))
    for items in todo.values():
        for k in range(0, len(items), SLEW_BATCH):
            _trace_slews(items[k:k + SLEW_BATCH])


def _trace_slews(items: list) -> None:
    """Trace and keep the slews of ``items`` ((pointing, end, starts, poses) sharing a source,
    targets and person zones, :func:`_batch_rays`)."""
    pointings = [p for p, _, _, _ in items]
    c, b, m = _batch_rays(pointings, [np.vstack(poses) for _, _, _, poses in items])
    margins = np.repeat([np.broadcast_to(p.path_margin_m(), (2,)) for p in pointings], m, axis=0)
    inside = pointings[0]._inside(c, b, margins).reshape(len(items), m, -1)
    for (p, end, starts, poses), rays in zip(items, inside, strict=True):
        p.keep_clear(starts, end, poses, rays)
