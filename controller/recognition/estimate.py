"""Magnitude of a recognised error: the beam's pointing error interpolated between library entries.

Every entry of a library built from a rendered error set records the beam pointing error of its
state (``az_deg``, ``el_deg``: Δazimuth, Δelevation of the reflected beam, degrees) and the
state's ``params`` (``magnitude`` = multiple of the case's nominal size, heliostat, source, ...).
Once the case is known, the estimate is the inverse-distance weighted mean over the ``k``
nearest entries *of that case* (distances in the library's matching space, w = 1/(d + ε)), so a
view between two library magnitudes gets an error between theirs. The coarse correction is its
negative: the move that puts the beam back.

Confidence in [0, 1] (0 when unknown) is the product of two margins:
``(1 - d / T)`` how far inside its unknown threshold T the match lies, and
``(1 - d / d_ru)`` how much nearer the case is than the runner-up case. Both must be clear for a
coarse correction to be worth applying (see docs/recognition.md for the measured precision).

Caveat: a pure pointing error (``tracking-offset``) does not change the spot's shape, so its size
cannot be read from the image; its estimate is the mean of its entries, and only the centroid
measures it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

K_NEIGHBOURS = 3
_EPS = 1e-12


@dataclass(frozen=True)
class Estimate:
    error_deg: tuple[float, float] | None
    coarse_correction_deg: tuple[float, float] | None
    magnitude: float | None
    confidence: float


def confidence(distance: float, threshold: float, runner_up_distance: float | None) -> float:
    """Product of the threshold margin and the runner-up margin, each clipped to [0, 1]."""
    inside = 1.0 - distance / threshold if np.isfinite(threshold) and threshold > 0 else 1.0
    apart = 1.0 - distance / runner_up_distance if runner_up_distance else 1.0
    return float(np.clip(inside, 0.0, 1.0) * np.clip(apart, 0.0, 1.0))


def _magnitude(params: dict | None) -> float | None:
    try:
        return float(params["magnitude"]) if params and params.get("magnitude") not in (None, "") else None
    except (TypeError, ValueError):
        return None


def estimate(lib, matcher, query: np.ndarray, m, k: int = K_NEIGHBOURS) -> Estimate:
    """Estimate for match ``m`` of the (transformed) ``query`` against ``lib`` / ``matcher``."""
    if m.unknown:
        return Estimate(None, None, None, 0.0)
    conf = confidence(m.distance, float(matcher.unknown_distance[m.index]), m.runner_up_distance)
    members = matcher.members[matcher.codes[m.index]]
    d = np.sqrt(np.sum((matcher.x[members] - query) ** 2, axis=1))
    order = members[np.argsort(d, kind="stable")]
    dist = np.sort(d, kind="stable")
    entries = [lib.entries[i] for i in order]

    def weighted(values: list[float | None]) -> float | None:
        ok = [(v, dd) for v, dd in zip(values, dist, strict=True) if v is not None][:k]
        if not ok:
            return None
        w = np.array([1.0 / (dd + _EPS) for _, dd in ok])
        return float(np.dot(w, [v for v, _ in ok]) / w.sum())

    has_azel = [e.az_deg is not None and e.el_deg is not None for e in entries]
    az = weighted([float(e.az_deg) if ok else None for e, ok in zip(entries, has_azel, strict=True)])
    el = weighted([float(e.el_deg) if ok else None for e, ok in zip(entries, has_azel, strict=True)])
    err = (az, el) if az is not None and el is not None else None
    magnitude = weighted([_magnitude(e.params) for e in entries])
    return Estimate(err, (-err[0], -err[1]) if err else None, magnitude, conf)
