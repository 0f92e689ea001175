"""Drift of a heliostat's joint references in time: a random walk over measurement sessions.

A heliostat's pointing wanders: on the 16 Jülich heliostats of the PAINT data set a fit to
the records of one season predicts the next season worse than a fit to the records just
before it (docs/tracking-model.md, "On real heliostats"). The fit models this as a random walk
of the two joint references (``az_offset``, ``el_offset``) over *sessions*, runs of
measurements without a gap of ``gap_days``. With d_e the references of session e relative to
the newest session (d_newest = 0) and Δt_e the days between sessions e and e + 1,

    d_{e+1} − d_e ~ N(0, (q Δt_e + j²) I₂),   q = σ_d²                                  (1)

σ_d (rad per √day) is the walk and j (rad) a jump between any two sessions (re-homing,
a night's temperature). A measurement of session e sees the model with its references moved
by d_e; the newest session's references are the model's. The prior (1) is a chain: the
precision of (d_0 … d_{E−2}) is LᵀL with L the scaled first differences of (1).

Parameterisation: d_e = u_e y_e with u_e = sqrt(Σ_{k ≥ e} (q Δt_k + j²)), the marginal σ of
d_e, so every y has unit prior scale.

Units: times in days (UTC, any origin); σ_d rad/√day; j rad.

References
----------
.. [1] A. Gelb (ed.), "Applied Optimal Estimation", MIT Press 1974, Sec. 4.3: random-walk
   state models; the fixed-interval smoother of a random walk is the MAP of (1).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

DRIFTING = ("az_offset", "el_offset")
# The jump between sessions of PAINT records (rad): what a day does to a Jülich heliostat's
# references beside the walk (docs/tracking-model.md, "On real heliostats").
PAINT_JUMP_RAD = 0.1e-3


@dataclass(frozen=True)
class RandomWalk:
    """The drift prior of Eq. (1): ``sigma_per_sqrt_day`` σ_d (rad/√day), ``jump`` j (rad)
    between sessions, and the gap (days) that separates two sessions."""

    sigma_per_sqrt_day: float
    jump: float = 0.0
    gap_days: float = 0.25

    def active(self) -> bool:
        return self.sigma_per_sqrt_day > 0.0 or self.jump > 0.0


@dataclass(frozen=True, eq=False)  # numpy fields
class Sessions:
    """Measurements grouped into sessions, oldest first: ``index`` (S,) the session of each
    measurement (the newest holds those without a time), ``times`` (E,) each session's last
    time (days), ``scale`` (E − 1,) u_e of the module docstring, ``step_sd`` (E − 1,) the
    σ of each difference of Eq. (1)."""

    index: np.ndarray
    times: np.ndarray
    scale: np.ndarray
    step_sd: np.ndarray

    @property
    def count(self) -> int:
        return len(self.times)


def sessions(times: Sequence[float | None], walk: RandomWalk) -> Sessions:
    """Group measurements at ``times`` (days, None: unknown, counted with the newest session)
    into sessions separated by more than ``walk.gap_days``, with the scales of Eq. (1)."""
    known = sorted(t for t in times if t is not None)
    if not known:
        return Sessions(np.zeros(len(times), int), np.zeros(1), np.zeros(0), np.zeros(0))
    bounds = [known[0]]
    ends = []
    for a, b in zip(known, known[1:], strict=False):
        if b - a > walk.gap_days:
            ends.append(a)
            bounds.append(b)
    ends.append(known[-1])
    starts = np.array(bounds)
    last = len(starts) - 1
    index = np.array([last if t is None else int(np.searchsorted(starts, t, side="right") - 1)
                      for t in times])
    ends_a = np.array(ends)
    gaps = np.maximum(starts[1:] - ends_a[:-1], 0.0)
    step_sd = np.sqrt(walk.sigma_per_sqrt_day**2 * gaps + walk.jump**2)
    scale = np.sqrt(np.cumsum((step_sd**2)[::-1])[::-1])
    return Sessions(index, ends_a, scale, step_sd)


def chain_precision(s: Sessions, components: int = len(DRIFTING)) -> np.ndarray:
    """LᵀL: the prior precision of the whitened offsets y (E − 1 sessions × ``components``,
    session-major) of Eq. (1), with d_newest = 0."""
    m = s.count - 1
    if m <= 0:
        return np.zeros((0, 0))
    diff = np.zeros((m, m))
    for e in range(m):
        diff[e, e] = -s.scale[e] / s.step_sd[e]
        if e + 1 < m:
            diff[e, e + 1] = s.scale[e + 1] / s.step_sd[e]
    return np.kron(diff.T @ diff, np.eye(components))


def offsets_at(session_times: np.ndarray, offsets: np.ndarray, t: float | None) -> np.ndarray:
    """The references' offsets from the newest session's (same unit as ``offsets`` (E, 2)) at
    time ``t`` (days): between two sessions the random walk's mean given both, the straight
    line between them (the Brownian bridge); before the first session the first's; at or
    after the newest, or at an unknown time, zero (the model as fitted)."""
    times, d = np.asarray(session_times, float), np.asarray(offsets, float)
    if t is None or len(times) == 0 or t >= times[-1]:
        return np.zeros(d.shape[1] if d.ndim == 2 else len(DRIFTING))
    return np.array([np.interp(t, times, d[:, c]) for c in range(d.shape[1])])
