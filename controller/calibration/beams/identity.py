"""The known step that tells a heliostat's spot from the others' in a shared capture (several
beams per target, :mod:`controller.calibration.beams.group`)."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from controller.calibration.beams.slots import IDENTITY_STEP_M
from controller.calibration.cycle.pointing import GeometryPointing
from controller.calibration.cycle.warm import batch_rays, in_batches, warm_aims, warm_slews
from controller.errors import HeliocalError
from controller.geometry.spot import hit_uv

PROBE = 1000.0  # steps: the spot's motion per step of each axis, from this far
PROBES = np.array([(0.0, 0.0), (PROBE, 0.0), (0.0, PROBE)])


def identity_step(pointing, pose: tuple[int, int], slot: int, k: int, frame, step_m: float = IDENTITY_STEP_M
                  ) -> tuple[tuple[int, int], np.ndarray]:
    """The known step of a heliostat at ``pose`` (motor steps, both ≥ 0: the approach ended
    moving up on both axes, so the step takes up no backlash) holding ``slot`` of ``k``, and
    its spot's predicted displacement (u, v) m on ``frame``: steps ∝ (cos θ / |∂uv/∂az|,
    sin θ / |∂uv/∂el|), θ = 90° · slot / (K − 1) — each axis counted in metres of spot motion, so
    the K displacements spread evenly from the azimuth's direction on the target to the
    elevation's whatever the axes' gearing (the tolerance of Eq. 1 is half the closest pair's
    distance) — scaled to move the spot about ``step_m`` (the layout's, ``SlotLayout.step_m``).
    The displacement is the reflected central ray's hit point on the target plane
    (:func:`controller.geometry.spot.hit_uv`) traced with the heliostat's model
    (``pointing.rays``) after the step minus before it."""
    base = np.array(pose, float)
    step = step_from_probes(*pointing.rays(base + PROBES), slot, k, frame, step_m)
    return step, displacement(*pointing.rays(base + np.array([(0, 0), step], float)), frame)


def step_from_probes(c: np.ndarray, b: np.ndarray, slot: int, k: int, frame,
                     step_m: float) -> tuple[int, int]:
    """:func:`identity_step`'s step from the rays (centres ``c``, beams ``b``, (3, 3)) at the pose
    and at the pose moved by :data:`PROBES`: the spot's motion per step of each axis, then the
    step of ``slot`` of ``k`` that moves it ``step_m``."""
    per_step = displacements(c, b, frame).T / PROBE  # m of (u, v) per step
    theta = 0.5 * math.pi * slot / max(k - 1, 1)
    want = np.array([math.cos(theta), math.sin(theta)]) / np.maximum(np.linalg.norm(per_step, axis=0), 1e-12)
    scale = step_m / max(float(np.linalg.norm(per_step @ want)), 1e-12)
    step = np.rint(want * scale).astype(int)
    return int(step[0]), int(step[1])


def displacement(c: np.ndarray, b: np.ndarray, frame) -> np.ndarray:
    """The spot's displacement (u, v) m on ``frame`` from the first ray to the second (2, 3)."""
    return displacements(c, b, frame)[0]


def displacements(c: np.ndarray, b: np.ndarray, frame) -> np.ndarray:
    """(n − 1, 2) m: where the rays after the first hit ``frame``'s plane, less where the first does
    (:func:`controller.geometry.spot.hit_uv`)."""
    uv = hit_uv(c, b, frame.center, frame.normal, frame.u, frame.v)
    return uv[1:] - uv[:1]


def identity_key(pose, slot: int, k: int, frame, step_m: float) -> tuple:
    """What an identity step is kept by (with the pointing's ray model, ``BeamSafety._kept``)."""
    return ("identity", float(pose[0]), float(pose[1]), int(slot), int(k), float(step_m),
            *(np.asarray(a, float).tobytes() for a in (frame.center, frame.normal, frame.u, frame.v)))


def kept_identity_step(pointing, pose: tuple[int, int], slot: int, k: int, frame,
                       step_m: float = IDENTITY_STEP_M) -> tuple[tuple[int, int], np.ndarray]:
    """:func:`identity_step`, kept by ``pointing`` (a :class:`BeamSafety`) for its ray model: a
    slot's check asks it of the aim pose (``slot_parks``), and the round's capture at that pose
    asks it again. The displacement returned is shared: not to be changed in place."""
    return pointing._kept(identity_key(pose, slot, k, frame, step_m),
                          lambda: identity_step(pointing, pose, slot, k, frame, step_m))


def warm_identity_steps(items: list[tuple]) -> None:
    """The identity steps of ``items`` ((pointing, pose, slot, k, frame, step_m)), traced for
    all of them in two evaluations of the model per batch and kept by each pointing as
    :func:`kept_identity_step` keeps them: each heliostat's rays are those its own trace gives,
    and its step and displacement are computed from them as :func:`identity_step` does."""
    todo = [it for it in items if it[0]._with_model(identity_key(*it[1:])) not in it[0]._poses]
    in_batches(todo, _trace_identity_steps)


def _trace_identity_steps(items: list[tuple]) -> None:
    ps, bases = [it[0] for it in items], [np.array(it[1], float) for it in items]
    c, b, _ = batch_rays(ps, [x + PROBES for x in bases])
    c, b = c.reshape(len(ps), 3, 3), b.reshape(len(ps), 3, 3)
    steps = [step_from_probes(c[i], b[i], *it[2:]) for i, it in enumerate(items)]
    c, b, _ = batch_rays(ps, [x + np.array([(0, 0), s], float) for x, s in zip(bases, steps, strict=True)])
    c, b = c.reshape(len(ps), 2, 3), b.reshape(len(ps), 2, 3)
    for (p, pose, slot, k, frame, step_m), s, ci, bi in zip(items, steps, c, b, strict=True):
        kept = (s, displacement(ci, bi, frame))
        p._kept(identity_key(pose, slot, k, frame, step_m), lambda kept=kept: kept)


def warm_slot_checks(at_slot: Mapping[tuple[int, int], GeometryPointing], layout, frame,
                     current: Mapping[str, tuple[int, int]]) -> None:
    """What a pass's slot checks (:func:`controller.calibration.beams.group.slot_parks`) ask of the
    slot each heliostat takes if every slot suits it (``at_slot``: (ticket, slot) → pointing;
    ``layout`` the pass's :class:`SlotLayout`), solved and traced in batches before they ask one
    at a time: the aims and their approaches (:func:`warm_aims`), the identity steps at the aims,
    and the direct slews to standby from where each stands (``current``, by id), from its aim and
    from its stepped pose (:func:`warm_slews`). What is out of reach is left to the checks."""
    warm_aims(at_slot.values(), approaches=True)
    todo = []
    for (_, slot), p in at_slot.items():
        try:
            if p.model is not None:  # without one a heliostat's beam is searched for: nothing to warm
                todo.append((p, p.aim_steps(p.model), *layout.rank(slot), frame, layout.step_m))
        except (HeliocalError, ValueError):
            continue
    warm_identity_steps(todo)
    slews = []
    for p, aim, slot, k, _, step_m in todo:
        step, _ = kept_identity_step(p, aim, slot, k, frame, step_m)
        stepped = (aim[0] + step[0], aim[1] + step[1])
        az, el = p.kin.azimuth, p.kin.elevation
        inside = az.min_steps <= stepped[0] <= az.max_steps and el.min_steps <= stepped[1] <= el.max_steps
        slews.append((p, (current.get(p.heliostat.id), aim, stepped if inside else None)))
    warm_slews(slews)
