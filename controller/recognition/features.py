"""Feature vectors of beam images for the error library, by feature kind.

Kinds (``FEATURE_KINDS``): ``hu`` (phi_1..phi_7 of the spot segmented at one threshold, the
paper's), ``log-hu`` (their signed logs), ``multi-hu`` (Hu at 0.1, 0.3, 0.5 of the peak),
``multi-lobe-hu`` (``multi-hu`` and, as a fourth row, Hu of *all* lobes above 0.1 of the peak:
:mod:`controller.recognition.lobes`; the default of ``heliocal library build``),
``blur-hu`` (blur-invariant Hu of the whole spot signal, made scale free:
:mod:`controller.recognition.blur_features`) and ``multi-blur-hu`` (the multi-hu stack and the
blur-hu features side by side). A kind's *descriptor stack* (:func:`describe`, rows x 7) is
what :meth:`~controller.recognition.library.Library.match_hu` takes; :func:`hu_features` turns
it into the feature vector the library stores.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from controller.errors import InputError
from controller.imaging.background import Background, estimate_background
from controller.imaging.beam import analyze, check_image
from controller.imaging.blur_moments import WINDOW_THRESHOLD, blur_invariant_hu
from controller.recognition.blur_features import blur_features
from controller.recognition.lobes import lobes_hu

FEATURE_KINDS = ("multi-lobe-hu", "multi-hu", "hu", "log-hu", "blur-hu", "multi-blur-hu")
MULTI_THRESHOLDS = (0.1, 0.3, 0.5)
# The lobe row: Hu of every region above this fraction of the peak (detached lobes included).
LOBE_ROW = (0.1,)
# The window row: blur-invariant Hu of the whole signal above this fraction of the peak (plus margin).
BLUR_ROW = (WINDOW_THRESHOLD,)


def kind_thresholds(kind: str, threshold: float) -> tuple[float, ...]:
    """The rows of a kind's descriptor stack: segmentation thresholds of its Hu vectors; a
    blur kind's last row is the blur-invariant Hu of the whole spot in the window found at
    :data:`BLUR_ROW` (:func:`controller.imaging.blur_moments.blur_invariant_hu`); ``multi-lobe-hu``'s
    last row is the Hu of all lobes above :data:`LOBE_ROW` (:func:`controller.recognition.lobes.lobes_hu`)."""
    return {"multi-hu": MULTI_THRESHOLDS, "multi-lobe-hu": MULTI_THRESHOLDS + LOBE_ROW, "blur-hu": BLUR_ROW,
            "multi-blur-hu": MULTI_THRESHOLDS + BLUR_ROW}.get(kind, (threshold,))


def library_width(kind: str) -> int:
    """Number of features of a kind: 7 per descriptor row, the blur row giving 6 (phi_1 dropped)."""
    rows = len(kind_thresholds(kind, 0.5))
    return 7 * rows - (1 if kind in ("blur-hu", "multi-blur-hu") else 0)
_LOG_FLOOR = 1e-30


def hu_stack(image: np.ndarray, thresholds: Sequence[float],
             background: Background | None = None) -> np.ndarray:
    """Hu moments (len(thresholds), 7) of the beam segmented at each threshold, above
    ``background`` (default: the σ-clipped plane, :func:`estimate_background`, estimated once
    for all thresholds: it does not depend on them)."""
    bg = estimate_background(check_image(image)) if background is None else background
    return np.array([analyze(image, threshold=t, background=bg, centroid="segment", presence=False).hu
                     for t in thresholds], dtype=np.float64)


def describe(image: np.ndarray, kind: str, threshold: float = 0.5) -> np.ndarray:
    """The descriptor stack (len(kind_thresholds), 7) of a beam image for a feature kind: Hu
    moments of the spot segmented at each threshold, and for a blur kind, as its last row, the
    blur-invariant Hu of the whole spot signal; for ``multi-lobe-hu`` the Hu of all its lobes
    (above the same plane)."""
    ts = kind_thresholds(kind, threshold)
    if kind == "multi-lobe-hu":
        bg = estimate_background(check_image(image))
        return np.vstack([hu_stack(image, ts[:-1], bg), lobes_hu(image, ts[-1], bg)[None, :]])
    if kind in ("blur-hu", "multi-blur-hu"):
        return np.vstack([hu_stack(image, ts[:-1]).reshape(-1, 7), blur_invariant_hu(image)[None, :]])
    return hu_stack(image, ts)


def hu_features(hu: np.ndarray, kind: str) -> np.ndarray:
    """Feature vector from a descriptor stack: raw (``hu``: 7, ``multi-hu``/``multi-lobe-hu``: the
    stack flattened), signed log (``log-hu``), or with the blur row turned into scale-free blur invariants
    (``blur-hu``, ``multi-blur-hu``: :func:`controller.recognition.blur_features.blur_features`)."""
    h = np.asarray(hu, dtype=np.float64)
    if kind in ("hu", "multi-hu", "multi-lobe-hu"):
        return h.reshape(-1).copy()
    if kind in ("blur-hu", "multi-blur-hu"):
        flat = h.reshape(-1)
        return np.concatenate([flat[:-7], blur_features(flat[-7:])])
    if kind == "log-hu":
        return -np.sign(h.reshape(-1)) * np.log10(np.maximum(np.abs(h.reshape(-1)), _LOG_FLOOR))
    raise InputError(f"feature kind must be one of {', '.join(FEATURE_KINDS)}, not {kind!r}")


def image_features(image: np.ndarray, kind: str, threshold: float = 0.5) -> np.ndarray:
    """Analyse a beam image (background auto) and return its feature vector (:func:`library_width`)."""
    return hu_features(describe(image, kind, threshold), kind)
