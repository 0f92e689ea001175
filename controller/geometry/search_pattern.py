"""The pattern of a beam search: where in the target plane to aim, one look after another, when a
heliostat's spot is not in the camera's view (docs/commissioning.md, "First light on a new field").

The looks lie on a grid of steps (s_u, s_v) over the target plane, centred on the predicted
spot (offset 0, 0), each step the camera's view less the overlap of neighbouring looks:

    s_u = W − 2 k σ_spot,   s_v = H − 2 k σ_spot                                            (1)

(W × H the view, σ_spot the predicted spot's 1-σ radius, k the overlap in σ): a spot whose centre
lies anywhere in the pattern is, in the look nearest to it, at least k σ_spot inside the view. The
pattern covers the ellipse of the beam's expected position out to ``radius`` (m, each axis), and
the looks go outwards in order of their distance from the centre counted in steps (a square
spiral on the grid), the same-distance looks by their angle, so the likeliest positions are
looked at first. The centre look is first.

Units: m in the target plane, u along the view's width (image x), v along its height (image y).
"""

from __future__ import annotations

import math

import numpy as np


def search_steps(view_m: tuple[float, float], spot_sigma_m: float,
                 overlap_sigma: float) -> tuple[float, float]:
    """(s_u, s_v) of Eq. (1), m; each at least a tenth of its view (a spot larger than the view
    is seen clipped from any look near it)."""
    w, h = (float(v) for v in view_m)
    grow = 2.0 * overlap_sigma * max(float(spot_sigma_m), 0.0)
    return max(w - grow, 0.1 * w), max(h - grow, 0.1 * h)


def spiral_offsets(step_m: tuple[float, float], radius_m: tuple[float, float], max_looks: int) -> np.ndarray:
    """The look offsets (N, 2) m (u, v), N ≤ ``max_looks``: the grid points of ``step_m`` inside the
    ellipse of semi-axes ``radius_m`` grown by half a step, nearest first (module docstring)."""
    su, sv = (float(v) for v in step_m)
    ru, rv = (max(float(v), 0.0) for v in radius_m)
    nu, nv = int(math.ceil(ru / su)), int(math.ceil(rv / sv))
    iu, iv = np.meshgrid(np.arange(-nu, nu + 1), np.arange(-nv, nv + 1), indexing="ij")
    iu, iv = iu.ravel(), iv.ravel()
    du, dv = iu * su, iv * sv
    inside = (du / (ru + su / 2.0)) ** 2 + (dv / (rv + sv / 2.0)) ** 2 <= 1.0
    ring = np.maximum(np.abs(iu), np.abs(iv))[inside]
    angle = np.mod(np.arctan2(iv, iu)[inside], 2.0 * math.pi)
    order = np.lexsort((angle, ring))
    return np.column_stack([du[inside], dv[inside]])[order][:max(int(max_looks), 0)]
