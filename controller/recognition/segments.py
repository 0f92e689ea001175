"""Which library entries the matcher interpolates between: neighbouring magnitudes of one case.

A library with a few sizes per error case (e.g. 0.5, 1, 1.5 times nominal) leaves gaps: a view of
an intermediate size lies between two entries of its case, about half their distance from each,
and can come nearer to an entry of another case. Joining neighbouring sizes by a segment (matched
as a line, :class:`controller.recognition.matching.Matcher`) interpolates the library linearly in
feature space between them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from controller.recognition.estimate import param_magnitude


def magnitude_segments(entries: Sequence, x: np.ndarray) -> np.ndarray:
    """Pairs (s, 2) of entry indices to interpolate between, all within one case.

    * Neighbouring magnitudes: entries of a case whose ``params.magnitude`` is known, grouped
      by their other params (heliostat, source, ...), joined in order of magnitude.
    * The case's minimum spanning tree in the matching space ``x`` (n, k) (Prim's algorithm):
      without magnitudes, for three sizes of one mechanism that is the chain small - medium -
      large (the middle size lies between the other two); across heliostats it joins each
      entry to the nearest geometry of its case, so a heliostat between two library ones is
      interpolated too.

    One entry alone has no segment; duplicates are dropped.
    """
    by_label: dict[str, list[int]] = {}
    for i, e in enumerate(entries):
        by_label.setdefault(e.label, []).append(i)
    pairs: list[tuple[int, int]] = []
    for idx in by_label.values():
        mags = [param_magnitude(entries[i].params) for i in idx]
        if all(m is not None for m in mags):
            groups: dict[tuple, list[tuple[float, int]]] = {}
            for i, m in zip(idx, mags, strict=True):
                params = (entries[i].params or {}).items()
                rest = tuple(sorted((k, str(v)) for k, v in params if k != "magnitude"))
                groups.setdefault(rest, []).append((m, i))
            for members in groups.values():
                members.sort()
                pairs += [(a, b) for (_, a), (_, b) in zip(members, members[1:], strict=False)]
        pairs += _spanning_tree(idx, x)
    unique = sorted({(min(a, b), max(a, b)) for a, b in pairs if a != b})
    return np.array(unique, dtype=np.int64).reshape(-1, 2)


def _spanning_tree(idx: list[int], x: np.ndarray) -> list[tuple[int, int]]:
    """Edges of the Euclidean minimum spanning tree of the points ``x[idx]`` (Prim)."""
    if len(idx) < 2:
        return []
    p = x[idx]
    d = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=2)
    inside = np.zeros(len(idx), dtype=bool)
    inside[0] = True
    best, parent = d[0].copy(), np.zeros(len(idx), dtype=np.int64)
    edges = []
    for _ in range(len(idx) - 1):
        cand = np.where(inside, np.inf, best)
        j = int(np.argmin(cand))
        edges.append((idx[int(parent[j])], idx[j]))
        inside[j] = True
        closer = d[j] < best
        best = np.where(closer, d[j], best)
        parent = np.where(closer, j, parent)
    return edges
