"""Several beam spots in one image: separate them, and tell whose spot is whose by a known step.

**Separation.** Pixels more than ``SNR`` background noise σ (median absolute deviation) above
the background (median) and above ``floor`` of the brightest pixel, grown by ``grow_px``
(a spot's dim lobes stay with it), form connected regions; each region of at least
``min_px`` pixels is one spot (:func:`spot_regions`). :func:`isolate` keeps one region and
replaces the others by the background, so the one-spot analysis sees that spot alone.

**Identity by a known step.** Between two captures every heliostat of the group moved by its
own known step, whose displacement on the target d_i is predicted from its model (distinct
directions, :data:`controller.calibration.slots.IDENTITY_STEP_M` long). A spot at a in the
first image and b in the second belong to heliostat i when

    |b − (a + d_i)| < tol,    tol = ½ min_{i≠j} |d_i − d_j|                          (1)

Heliostat i's spot is *confirmed* when exactly one pair (a, b) satisfies (1) for i, no other
heliostat's displacement explains that pair, both images hold exactly one spot per heliostat,
and a is also the spot nearest i's slot (position and motion agree). Anything else — a spot
missing, an extra spot, two candidates, a spot that moved with i but sits at another's slot
— is *ambiguous*: the heliostat is measured again alone (:mod:`controller.calibration.group`).

Units: positions and displacements in metres on the target plane (u, v); image x = column,
y = row.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

SNR = 8.0


def spot_regions(hdr: np.ndarray, *, floor: float = 0.02, grow_px: int = 3, min_px: int = 4
                 ) -> tuple[np.ndarray, int]:
    """Label image (int, 0 = background) and count of the spots of ``hdr`` (module docstring)."""
    img = np.asarray(hdr, float)
    bg = float(np.median(img))
    noise = 1.4826 * float(np.median(np.abs(img - bg))) or 1e-12
    sig = img - bg
    peak = float(sig.max()) if sig.size else 0.0
    mask = (sig > SNR * noise) & (sig > floor * peak)
    if grow_px > 0:
        mask = ndimage.binary_dilation(mask, iterations=grow_px)
    labels, n = ndimage.label(mask)
    if n == 0:
        return labels, 0
    sizes = ndimage.sum_labels(np.ones_like(labels), labels, index=np.arange(1, n + 1))
    keep = np.flatnonzero(sizes >= min_px) + 1
    out = np.zeros_like(labels)
    for new, old in enumerate(keep, start=1):
        out[labels == old] = new
    return out, len(keep)


def centroids_px(hdr: np.ndarray, labels: np.ndarray, count: int) -> np.ndarray:
    """Energy centroid (x, y) px of each labelled spot (count, 2), background subtracted."""
    sig = np.clip(np.asarray(hdr, float) - float(np.median(hdr)), 0.0, None)
    if count == 0:
        return np.zeros((0, 2))
    idx = np.arange(1, count + 1)
    rows, cols = np.indices(sig.shape)
    w = ndimage.sum_labels(sig, labels, idx)
    w = np.where(w > 0, w, 1.0)
    return np.stack([ndimage.sum_labels(sig * cols, labels, idx) / w,
                     ndimage.sum_labels(sig * rows, labels, idx) / w], axis=-1)


def isolate(hdr: np.ndarray, labels: np.ndarray, keep: int) -> np.ndarray:
    """``hdr`` with every spot but label ``keep`` replaced by the background level."""
    img = np.asarray(hdr, float).copy()
    img[(labels > 0) & (labels != keep)] = float(np.median(img))
    return img


def assign_by_step(first_m: np.ndarray, second_m: np.ndarray, slots_m: np.ndarray, steps_m: np.ndarray
                   ) -> list[int | None]:
    """Per heliostat i (rows of ``slots_m`` (n, 2), its slot, and ``steps_m`` (n, 2), its
    predicted displacement): the index of its spot in ``first_m`` (m, 2), or None when
    ambiguous (module docstring, Eq. 1). ``second_m`` (m', 2): the spots after the step."""
    n = len(slots_m)
    a, b = np.asarray(first_m, float).reshape(-1, 2), np.asarray(second_m, float).reshape(-1, 2)
    d = np.asarray(steps_m, float).reshape(-1, 2)
    if len(a) != n or len(b) != n or n == 0:
        return [None] * n
    if n == 1:
        pair = np.linalg.norm(b[0] - a[0] - d[0]) < 0.5 * np.linalg.norm(d[0])
        return [0 if pair else None]
    gaps = [np.linalg.norm(d[i] - d[j]) for i in range(n) for j in range(n) if i != j]
    tol = 0.5 * min(gaps)
    # moved[i, p, q]: spot p of the first image went to spot q of the second by heliostat i's step
    moved = np.linalg.norm(b[None, None, :, :] - a[None, :, None, :] - d[:, None, None, :], axis=-1) < tol
    slots = np.asarray(slots_m, float)
    nearest = np.argmin(np.linalg.norm(a[None, :, :] - slots[:, None, :], axis=-1), axis=1)
    out: list[int | None] = []
    for i in range(n):
        pairs = np.argwhere(moved[i])
        if len(pairs) != 1:
            out.append(None)
            continue
        p, q = pairs[0]
        others = [j for j in range(n) if j != i and moved[j, p, q]]
        out.append(int(p) if not others and nearest[i] == p else None)
    return out
