"""Nearest-neighbour recognition of a beam's error case by Euclidean distance of Hu features.

d(q, e) = sqrt(sum_i (q_i - e_i)^2) over the 7 (optionally scaled) features (paper Eq. 14).
Optionally, *segments* join entries of one case that differ only in the error's magnitude: the
distance to a segment [a, b] is the Euclidean distance to its nearest point
p = a + t (b - a), t = clip((q - a)·(b - a) / |b - a|^2, 0, 1), i.e. to the library entry
linearly interpolated between two neighbouring magnitudes (a view between two library sizes
then lies on or near its case's segment instead of half-way between two entries).
The best entry (or segment) gives the label; the runner-up is the nearest entry with a *different* label,
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
class Nearest:
    """The matcher's answer to one query: the nearest entry (or segment) and the nearest entry
    of another label. Distances are in (scaled) feature units. The library turns it into its
    :class:`controller.recognition.library.Match`."""

    label: str
    distance: float
    index: int
    runner_up_label: str | None
    runner_up_distance: float | None
    unknown: bool
    toward: int | None = None  # on a segment: the entry at its other end (index = the nearer end)
    fraction: float = 0.0  # on a segment: position from ``index`` towards ``toward``, in [0, 0.5]


class Matcher:
    """Vectorised Euclidean nearest-neighbour search over library features.

    Parameters
    ----------
    features : ndarray (n, 7) of library features (already transformed, e.g. log-Hu).
    labels : sequence of n labels.
    scale : ndarray (7,) dividing every feature before the distance (1 = paper's raw Eq. 14).
    unknown_distance : best distances above this are reported as unknown (inf = never); a
        scalar, or one threshold per entry (n,) applied to the best entry (on a segment:
        interpolated between its two ends).
    segments : optional (s, 2) entry indices; each pair (same label) is matched as the line
        segment between the two entries as well as at its ends.
    """

    def __init__(self, features: np.ndarray, labels, scale: np.ndarray | None = None,
                 unknown_distance: float | np.ndarray = float("inf"),
                 segments: np.ndarray | None = None) -> None:
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
        seg = np.zeros((0, 2), dtype=np.int64) if segments is None else np.asarray(segments, dtype=np.int64)
        seg = seg.reshape(-1, 2)
        if seg.size and (seg.min() < 0 or seg.max() >= x.shape[0]
                         or np.any(self.codes[seg[:, 0]] != self.codes[seg[:, 1]])):
            raise ValueError("segments must join two entries of the same label")
        self.segments = seg
        self.seg_a = self.x[seg[:, 0]] - self.center  # (s, k), centred like the search arrays
        self.seg_d = self.x[seg[:, 1]] - self.x[seg[:, 0]]
        self.seg_dd = np.maximum(np.einsum("ij,ij->i", self.seg_d, self.seg_d), 1e-300)
        self.seg_codes = self.codes[seg[:, 0]]

    def distances(self, query: np.ndarray) -> np.ndarray:
        """Euclidean distances (n,) from one query feature vector (k,) to every entry (float64)."""
        q = np.asarray(query, dtype=np.float64) / self.scale
        return np.sqrt(np.einsum("ij,ij->i", self.x - q, self.x - q))

    def _exact(self, index: int, q: np.ndarray) -> float:
        d = self.x[index] - q
        return float(np.sqrt(d @ d))

    def match(self, query: np.ndarray) -> Nearest:
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
        d2 = d2.astype(np.float64)
        n = d2.size
        t = np.empty(0)
        if self.segments.size:
            # |q - a - t d|^2 - |q|^2 in the same centred frame as d2: comparable with it.
            qa = (q - self.center) - self.seg_a
            t = np.clip(np.einsum("ij,ij->i", qa, self.seg_d) / self.seg_dd, 0.0, 1.0)
            seg2 = np.einsum("ij,ij->i", qa, qa) - t * (2.0 * np.einsum("ij,ij->i", qa, self.seg_d)
                                                        - t * self.seg_dd)
            d2 = np.concatenate([d2, seg2 - float((q - self.center) @ (q - self.center))])
        codes = np.concatenate([self.codes, self.seg_codes])
        best = int(np.argmin(d2))
        d2[codes == codes[best]] = np.inf  # runner-up: best of the other labels
        ru = int(np.argmin(d2))
        has_ru = bool(np.isfinite(d2[ru]))
        index, toward, frac, dist = self._resolve(best, q, t, n)
        ru_dist = self._resolve(ru, q, t, n)[3] if has_ru else None
        limit = self.unknown_distance[index]
        if toward is not None:
            limit = (1.0 - frac) * limit + frac * self.unknown_distance[toward]
        return Nearest(
            label=self.labels[index], distance=dist, index=index,
            runner_up_label=self.labels[self._end(ru, n)] if has_ru else None,
            runner_up_distance=ru_dist,
            unknown=bool(dist > limit), toward=toward, fraction=frac,
        )

    def _end(self, k: int, n: int) -> int:
        """Entry index of candidate ``k`` (an entry, or the first end of segment ``k - n``)."""
        return k if k < n else int(self.segments[k - n, 0])

    def _resolve(self, k: int, q: np.ndarray, t: np.ndarray, n: int) -> tuple[int, int | None, float, float]:
        """(nearer entry, other end or None, fraction towards it, exact float64 distance) of candidate k."""
        if k < n:
            return k, None, 0.0, self._exact(k, q)
        a, b = (int(v) for v in self.segments[k - n])
        tk = float(t[k - n])
        if tk in (0.0, 1.0):  # the segment's nearest point is one of its ends
            end = a if tk == 0.0 else b
            return end, None, 0.0, self._exact(end, q)
        p = self.x[a] + tk * (self.x[b] - self.x[a])
        dist = float(np.sqrt((q - p) @ (q - p)))
        return (a, b, tk, dist) if tk <= 0.5 else (b, a, 1.0 - tk, dist)

