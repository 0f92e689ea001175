"""Magnitude of a recognised error: the beam's pointing error interpolated between library entries.

Every entry of a library built from a rendered error set records the beam pointing error of its
state (``az_deg``, ``el_deg``: Δazimuth, Δelevation of the reflected beam, degrees) and the
state's ``params`` (``magnitude`` = multiple of the case's nominal size, heliostat, source, ...).
When the match lies on a segment between two neighbouring magnitudes of the case
(:mod:`controller.recognition.matching`), the estimate is the linear interpolation of the two
entries at the match's position on it. Otherwise it is the inverse-distance weighted mean over
the ``k`` nearest entries *of that case* (distances in the library's matching space, w = 1/(d + ε)), so a
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


def param_magnitude(params: dict | None) -> float | None:
    """An entry's ``params.magnitude`` as a number (None when absent or not a number)."""
    try:
        return float(params["magnitude"]) if params and params.get("magnitude") not in (None, "") else None
    except (TypeError, ValueError):
        return None


def _along_segment(a, b, f: float, conf: float) -> Estimate:
    """Linear interpolation a + f (b - a) of two entries' pointing error and magnitude: the match
    lies on the segment between neighbouring magnitudes at fraction ``f`` from ``a``."""

    def lerp(u: float | None, v: float | None) -> float | None:
        return None if u is None or v is None else float(u + f * (v - u))

    az, el = lerp(a.az_deg, b.az_deg), lerp(a.el_deg, b.el_deg)
    err = (az, el) if az is not None and el is not None else None
    mag = lerp(param_magnitude(a.params), param_magnitude(b.params))
    return Estimate(err, (-err[0], -err[1]) if err else None, mag, conf)


def estimate(lib, matcher, query: np.ndarray, m, k: int = K_NEIGHBOURS) -> Estimate:
    """Estimate for match ``m`` of the (transformed) ``query`` against ``lib`` / ``matcher``."""
    if m.unknown:
        return Estimate(None, None, None, 0.0)
    threshold = float(matcher.unknown_distance[m.index])
    if m.toward is not None:
        threshold = (1.0 - m.fraction) * threshold + m.fraction * float(matcher.unknown_distance[m.toward])
        return _along_segment(lib.entries[m.index], lib.entries[m.toward], m.fraction,
                              confidence(m.distance, threshold, m.runner_up_distance))
    conf = confidence(m.distance, threshold, m.runner_up_distance)
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
    magnitude = weighted([param_magnitude(e.params) for e in entries])
    return Estimate(err, (-err[0], -err[1]) if err else None, magnitude, conf)
