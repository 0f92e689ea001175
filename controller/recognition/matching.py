"""Nearest-neighbour recognition of a beam's error case by Euclidean distance of Hu features.

d(q, e) = sqrt(sum_i (q_i - e_i)^2) over the 7 (optionally scaled) features (paper Eq. 14).
The best entry gives the label; the runner-up is the nearest entry with a *different* label,
so that the margin between the two says how confident the match is. A query whose best
distance exceeds that entry's ``unknown_distance`` (calibrated from the library's own spread,
see :mod:`controller.recognition.library`) is reported as unknown rather than issuing a
correction from the wrong case.

The search is a single matrix-vector product over a precomputed (n, 7) array:
|q - e|^2 = |e|^2 - 2 e.q + |q|^2, so 100,000 entries cost under 1 ms per query
(``benchmarks/bench_beam.py``).

References
----------
.. [1] M.-K. Hu, "Visual pattern recognition by moment invariants", IRE Trans. Inf. Theory
   8(2), 179-187, 1962.
.. [2] Heliostat error recognition by Hu moments and Euclidean distance, Eq. (14) and Table 4
   (the paper this project's recognition method follows; see docs/recognition.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Match:
    """Result of one query. Distances are in (scaled) feature units."""

    label: str
    distance: float
    index: int
    runner_up_label: str | None
    runner_up_distance: float | None
    unknown: bool


class Matcher:
    """Vectorised Euclidean nearest-neighbour search over library features.

    Parameters
    ----------
    features : ndarray (n, 7) of library features (already transformed, e.g. log-Hu).
    labels : sequence of n labels.
    scale : ndarray (7,) dividing every feature before the distance (1 = paper's raw Eq. 14).
    unknown_distance : best distances above this are reported as unknown (inf = never); a
        scalar, or one threshold per entry (n,) applied to the best entry.
    """

    def __init__(self, features: np.ndarray, labels, scale: np.ndarray | None = None,
                 unknown_distance: float | np.ndarray = float("inf")) -> None:
        x = np.asarray(features, dtype=np.float64)
        if x.ndim != 2 or x.shape[0] == 0:
            raise ValueError(f"library features must be a non-empty (n, k) array, got {x.shape}")
        self.labels = [str(v) for v in labels]
        if len(self.labels) != x.shape[0]:
            raise ValueError("one label per library entry is required")
        self.scale = np.ones(x.shape[1]) if scale is None else np.asarray(scale, dtype=np.float64)
        self.names, codes = np.unique(np.array(self.labels), return_inverse=True)
        self.codes = codes.astype(np.int64)
        self.members = [np.flatnonzero(self.codes == k) for k in range(len(self.names))]
        self.x = np.ascontiguousarray(x / self.scale)
        # The search runs in float32 on features centred on the library mean (halves the memory
        # traffic; centring keeps |e|^2 small so the expansion below loses no useful digits);
        # the two winners' distances are then recomputed exactly in float64.
        self.center = self.x.mean(axis=0)
        self.cols32 = np.ascontiguousarray((self.x - self.center).T, dtype=np.float32)  # (k, n)
        self.sq32 = np.einsum("ij,ij->j", self.cols32, self.cols32)
        self.unknown_distance = np.broadcast_to(np.asarray(unknown_distance, dtype=np.float64), (x.shape[0],))

    def distances(self, query: np.ndarray) -> np.ndarray:
        """Euclidean distances (n,) from one query feature vector (k,) to every entry (float64)."""
        q = np.asarray(query, dtype=np.float64) / self.scale
        return np.sqrt(np.einsum("ij,ij->i", self.x - q, self.x - q))

    def _exact(self, index: int, q: np.ndarray) -> float:
        d = self.x[index] - q
        return float(np.sqrt(d @ d))

    def match(self, query: np.ndarray) -> Match:
        """Nearest entry and nearest entry of another label (Eq. 14)."""
        q = np.asarray(query, dtype=np.float64) / self.scale
        qc = -2.0 * (q - self.center)
        # |q - e|^2 - |q|^2 = |e|^2 - 2 e.q, accumulated one feature column at a time: k
        # streaming passes, no BLAS call (a threaded gemv is ~10x slower on a busy 2-core host).
        d2 = self.sq32.copy()
        tmp = np.empty_like(d2)
        for col, qk in zip(self.cols32, qc.astype(np.float32), strict=True):
            np.multiply(col, qk, out=tmp)
            d2 += tmp
        best = int(np.argmin(d2))
        d2[self.members[self.codes[best]]] = np.inf  # runner-up: best of the other labels
        ru = int(np.argmin(d2))
        has_ru = bool(np.isfinite(d2[ru]))
        dist = self._exact(best, q)
        return Match(
            label=self.labels[best], distance=dist, index=best,
            runner_up_label=self.labels[ru] if has_ru else None,
            runner_up_distance=self._exact(ru, q) if has_ru else None,
            unknown=bool(dist > self.unknown_distance[best]),
        )

