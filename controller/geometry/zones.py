"""Person zones: whether a reflected beam enters a box where people may be.

A zone is an axis-aligned box in ENU metres, ``boxes[k] = (min_enu, max_enu)``, already grown
by its margin. The beam is the reflected central ray from the mirror centre; it ends where it
lands on a target (the target stops it), else it runs on without limit.
"""

from __future__ import annotations

import numpy as np


def ray_box_entry(origin: np.ndarray, direction: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float | None:
    """Distance t ≥ 0 (in units of ``direction``) at which the ray origin + t·direction enters
    the box [lo, hi], 0 when it starts inside, None when it misses — the slab method (Kay &
    Kajiya 1986): per axis the ray is between the two planes for t in
    [(lo−o)/d, (hi−o)/d] (ordered), and it is in the box on the intersection of the three
    intervals, t_near = max of the lower ends ≤ t_far = min of the upper ends, with t_far ≥ 0.
    An axis with d ≈ 0 is either always (lo ≤ o ≤ hi) or never between its planes."""
    o, d = np.asarray(origin, float), np.asarray(direction, float)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    t_near, t_far = 0.0, np.inf
    for k in range(3):
        if abs(d[k]) < 1e-12:  # parallel to this axis's planes (1e-12: no overflow in the division)
            if not lo[k] <= o[k] <= hi[k]:
                return None
            continue
        a, b = (lo[k] - o[k]) / d[k], (hi[k] - o[k]) / d[k]
        t_near, t_far = max(t_near, min(a, b)), min(t_far, max(a, b))
        if t_near > t_far:
            return None
    return float(t_near)


def zone_entered(origin: np.ndarray, direction: np.ndarray, boxes: np.ndarray,
                 max_t: float = np.inf) -> int | None:
    """Index of the first box of ``boxes`` (shape (n, 2, 3): min and max corner, m ENU) that the
    ray enters before ``max_t`` (where something stops the beam), else None."""
    best = None
    for k, (lo, hi) in enumerate(np.asarray(boxes, float).reshape(-1, 2, 3)):
        t = ray_box_entry(origin, direction, lo, hi)
        if t is not None and t < max_t and (best is None or t < best[0]):
            best = (t, k)
    return None if best is None else best[1]


def rays_enter_any(origins: np.ndarray, directions: np.ndarray, boxes: np.ndarray,
                   max_t: float = np.inf) -> np.ndarray:
    """For each ray origin + t·direction ((N, 3) each), whether it enters any box of ``boxes``
    (n, 2, 3) before ``max_t`` (a number, or one per ray) — :func:`ray_box_entry`'s slab method
    for all rays and boxes at once: (N,) bool."""
    o = np.asarray(origins, float)[:, None, :]
    d = np.asarray(directions, float)[:, None, :]
    b = np.asarray(boxes, float).reshape(-1, 2, 3)
    lo, hi = b[None, :, 0, :], b[None, :, 1, :]
    flat = np.abs(d) < 1e-12
    with np.errstate(divide="ignore", invalid="ignore"):
        a, c = (lo - o) / d, (hi - o) / d
    near = np.where(flat, -np.inf, np.minimum(a, c)).max(axis=-1)
    far = np.where(flat, np.inf, np.maximum(a, c)).min(axis=-1)
    inside_flat = np.all(~flat | ((lo <= o) & (o <= hi)), axis=-1)
    t = np.maximum(near, 0.0)
    return np.any(inside_flat & (t <= far) & (t < np.reshape(max_t, (-1, 1))), axis=-1)


def zone_boxes(zones) -> np.ndarray:
    """The (n, 2, 3) boxes of config ``person_zones`` (each with ``min_enu_m``, ``max_enu_m``,
    ``margin_m``), grown by their margins."""
    return np.array([[np.subtract(z.min_enu_m, z.margin_m), np.add(z.max_enu_m, z.margin_m)] for z in zones],
                    float).reshape(-1, 2, 3)
