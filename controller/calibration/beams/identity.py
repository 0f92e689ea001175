"""The known step that tells a heliostat's spot from the others' in a shared capture (several
beams per target, :mod:`controller.calibration.beams.group`)."""

from __future__ import annotations

import math

import numpy as np

from controller.calibration.beams.slots import IDENTITY_STEP_M
from controller.geometry.spot import hit_uv


def identity_step(pointing, pose: tuple[int, int], slot: int, k: int, frame, step_m: float = IDENTITY_STEP_M
                  ) -> tuple[tuple[int, int], np.ndarray]:
    """:func:`traced_identity_step`, kept by ``pointing`` for its ray model (``BeamSafety.kept``):
    a slot's check (:func:`controller.calibration.beams.group.slot_parks`) and the capture at
    the aim ask for the same step (issue 42: two traces per measurement)."""
    key = ("identity", *(int(s) for s in pose), int(slot), int(k), float(step_m),
           *(np.asarray(a, float).tobytes() for a in (frame.center, frame.normal, frame.u, frame.v)))
    return pointing.kept(key, lambda: traced_identity_step(pointing, pose, slot, k, frame, step_m))


def traced_identity_step(pointing, pose: tuple[int, int], slot: int, k: int, frame,
                         step_m: float = IDENTITY_STEP_M) -> tuple[tuple[int, int], np.ndarray]:
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

    def moved(steps) -> np.ndarray:  # (n, 2) steps -> (n, 2) m of (u, v)
        c, b = pointing.rays(base + np.asarray(steps, float))
        uv = hit_uv(c, b, frame.center, frame.normal, frame.u, frame.v)
        return uv[1:] - uv[:1]

    probe = 1000.0
    per_step = moved([(0, 0), (probe, 0), (0, probe)]).T / probe  # m of (u, v) per step
    theta = 0.5 * math.pi * slot / max(k - 1, 1)
    want = np.array([math.cos(theta), math.sin(theta)]) / np.maximum(np.linalg.norm(per_step, axis=0), 1e-12)
    scale = step_m / max(float(np.linalg.norm(per_step @ want)), 1e-12)
    step = np.rint(want * scale).astype(int)
    return (int(step[0]), int(step[1])), moved([(0, 0), tuple(step)])[0]
