"""The library's own spread: how far later views of one case stray from its entry, and what the
library learns from that (the feature scale or whitening of the distance, and every entry's
unknown threshold).

Pure: feature deviations in (from :func:`controller.recognition.library.augmented_views` of the
library's own images), numpy out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

UNKNOWN_FACTOR = 3.0


@dataclass(frozen=True)
class Spread:
    """Within-case spread of a library, from augmented views of its own images.

    ``deviations``: (m, 7) feature deviations of augmented views from their entry (in feature
    units, unscaled); ``owner``: (m,) index of the entry each deviation belongs to.
    """

    deviations: np.ndarray
    owner: np.ndarray


def feature_scale(spread: Spread, kind: str) -> np.ndarray:
    """Per-feature divisor of the distance.

    ``hu``: 1 (the paper's raw Euclidean distance, Eq. 14). ``log-hu``: the pooled within-case
    RMS deviation of each feature, i.e. a diagonal Mahalanobis distance, so that phi_5..phi_7 of
    near-symmetric spots (log of noise) weigh as little as they deserve. Floored at 1e-5 of the
    largest value so a perfectly stable feature cannot dominate.
    """
    k = spread.deviations.shape[1] if spread.deviations.size else 7
    if kind == "hu" or spread.deviations.shape[0] == 0:
        return np.ones(k)
    rms = np.sqrt(np.mean(spread.deviations**2, axis=0))
    top = float(rms.max())
    if top == 0.0:
        return np.ones(k)
    return np.maximum(rms, 1e-5 * top)


def whitening(x: np.ndarray, spread: Spread, floor: float = 1e-6) -> np.ndarray:
    """ZCA whitening W = C^(-1/2) (k, k) learned from the library's own *within-case* spread.

    C = second moment of the augmented views' deviations from their entry (framing, zoom, blur:
    the nuisances a later view of the same case will have), i.e. a Mahalanobis distance whose
    covariance is the nuisance alone, as in Fisher's discriminant: directions the nuisances
    hardly move (where the cases differ) keep their weight, directions they move a lot (spot
    size, noise of phi_5..phi_7) are shrunk. Adding the covariance of the entries themselves
    (how the cases differ) shrank exactly the directions that separate them: on the independent
    sets of docs/recognition.md that cost 3-13 points. Without deviations, C = covariance of
    the entries ``x`` (n, k). Eigenvalues are floored at ``floor`` x the largest, so a direction
    in which nothing varies is not blown up beyond 1/sqrt(floor). The distance is still the
    Euclidean distance of Eq. 14, on W f.
    """
    x = np.asarray(x, dtype=np.float64)
    k = x.shape[1]
    if spread.deviations.size:
        c = spread.deviations.T @ spread.deviations / spread.deviations.shape[0]
    else:
        c = np.cov(x.T, bias=True).reshape(k, k) if x.shape[0] > 1 else np.zeros((k, k))
    w, v = np.linalg.eigh(c)
    if not w.max() > 0:
        return np.eye(k)
    w = np.maximum(w, floor * w.max())
    return (v / np.sqrt(w)) @ v.T


def neighbour_thresholds(x: np.ndarray, labels: Sequence[str]) -> np.ndarray:
    """Per entry, the distance (in the matching space) to the nearest other entry of the same case
    (inf when it has none): a view of a magnitude between two library magnitudes lies about
    that far from the nearer one, and must not be rejected as unknown."""
    lab = np.asarray(labels)
    out = np.full(len(lab), np.inf)
    for i in range(len(lab)):
        same = (lab == lab[i]) & (np.arange(len(lab)) != i)
        if same.any():
            out[i] = float(np.min(np.linalg.norm(x[same] - x[i], axis=1)))
    return out


def unknown_thresholds(spread: Spread, scale: np.ndarray, n_entries: int,
                       factor: float = UNKNOWN_FACTOR) -> np.ndarray:
    """Per-entry unknown threshold, shape (n_entries,).

    T_i = ``factor`` x the 95th percentile of the scaled distances between augmented views and
    their entry, taken over the whole library (the augmentation models framing, not sensor
    noise, so one entry's own spread can be unrepresentatively small), and raised to the same
    statistic of entry i's own views where that is larger (shapes sensitive to framing).
    Inf when there is no spread to calibrate from.
    """
    d = np.sqrt(np.sum((spread.deviations / scale) ** 2, axis=1)) if spread.deviations.size else np.empty(0)
    overall = float(factor * np.percentile(d, 95)) if d.size else float("inf")
    out = np.full(n_entries, overall)
    for i in range(n_entries):
        own = d[spread.owner == i]
        if own.size:
            out[i] = max(overall, float(factor * np.percentile(own, 95)))
    return out
