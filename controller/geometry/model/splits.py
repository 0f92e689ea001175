"""Splits of one heliostat's calibration records into training, validation and test sets.

PAINT's benchmark splits (the PAINT database, Nature Energy 2026; ``paint/data/dataset_splits.py``),
per heliostat with sizes N_train and N_val, the rest test unless said otherwise:

* **azimuth**: records sorted by sun azimuth (then time); the N_train smallest train, the N_val
  largest validate — the model must extrapolate to the other side of the sky;
* **solstice**: the N_train nearest the winter solstice (21 December, 12:00 UTC) train, the
  N_val nearest the summer solstice (21 June) validate — the other season;
* **balanced**: KMeans with N_val clusters on (sun azimuth, sun elevation); one validation and
  one test record per cluster (those nearest its centre), training from the rest;
* **knn** (PAINT's "high variance"): each record's mean distance to its 3 nearest neighbours in
  (azimuth, elevation); the sparsest validate and test, the densest N_train train;

and ours, what calibration is for — the future:

* **time**: the last N_test records test, the N_train just before them train;
* **first**: the last N_test records test, the first N_train train (months or years before).

Each function returns index arrays (train, validation, test) into the records as given;
``times`` in days (any origin, UTC), sun angles in degrees (azimuth clockwise from north).
Distances in (azimuth, elevation) are in degrees.
"""

from __future__ import annotations

import numpy as np
from scipy.cluster.vq import kmeans2

SPLITS = ("time", "first", "azimuth", "solstice", "balanced", "knn")
_WINTER, _SUMMER = (12, 21), (6, 21)


def _days_to(times: np.ndarray, month_day: tuple[int, int]) -> np.ndarray:
    """Days from each time (days since 1970 UTC) to the nearest (month, day) 12:00 UTC of any year."""
    import datetime as dt

    out = np.empty(len(times))
    for k, t in enumerate(times):
        when = dt.datetime(1970, 1, 1, tzinfo=dt.UTC) + dt.timedelta(days=float(t))
        best = np.inf
        for year in (when.year - 1, when.year, when.year + 1):
            anchor = dt.datetime(year, *month_day, 12, tzinfo=dt.UTC)
            best = min(best, abs((when - anchor).total_seconds()) / 86400.0)
        out[k] = best
    return out


def split(kind: str, times, sun_az_deg, sun_el_deg, *, n_train: int, n_val: int = 0,
          n_test: int = 10, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(train, validation, test) indices of split ``kind`` (:data:`SPLITS`) for records at
    ``times`` with sun angles ``sun_az_deg``, ``sun_el_deg``. ValueError for an unknown kind or
    sizes the records cannot fill."""
    t = np.asarray(times, float)
    pts = np.column_stack([np.asarray(sun_az_deg, float), np.asarray(sun_el_deg, float)])
    n = len(t)
    order = np.lexsort((np.arange(n), t))  # by time, ties in given order
    if kind in ("time", "first"):
        if n_train + n_test > n:
            raise ValueError(f"{n} records cannot give {n_train} training and {n_test} test records")
        test = order[n - n_test:]
        train = order[n - n_test - n_train:n - n_test] if kind == "time" else order[:n_train]
        return np.sort(train), np.array([], int), np.sort(test)
    if kind in ("azimuth", "solstice"):
        if n_train + n_val >= n:
            raise ValueError(f"{n} records cannot give {n_train} training, {n_val} validation "
                             "and a test record")
        if kind == "azimuth":
            ranked = np.lexsort((t, pts[:, 0]))
            train, val = ranked[:n_train], ranked[n - n_val:] if n_val else np.array([], int)
        else:
            winter, summer = _days_to(t, _WINTER), _days_to(t, _SUMMER)
            train = np.lexsort((t, winter))[:n_train]
            rest = np.setdiff1d(np.arange(n), train)
            val = rest[np.lexsort((t[rest], summer[rest]))][:n_val]
        test = np.setdiff1d(np.arange(n), np.concatenate([train, val]))
        return np.sort(train), np.sort(val), test
    if kind == "balanced":
        if n_val < 1 or 2 * n_val + n_train > n:
            raise ValueError(f"{n} records cannot give {n_val} clusters of a validation and a test record "
                             f"and {n_train} training records")
        centres, label = kmeans2(pts, n_val, seed=seed, minit="++")
        val, test = [], []
        for c in range(n_val):
            members = np.flatnonzero(label == c)
            if len(members) < 2:
                continue
            near = members[np.argsort(np.linalg.norm(pts[members] - centres[c], axis=1), kind="stable")]
            val.append(near[0])
            test.append(near[1])
        rest = np.setdiff1d(np.arange(n), val + test)
        return np.sort(rest[np.argsort(t[rest], kind="stable")][-n_train:]), np.sort(val), np.sort(test)
    if kind == "knn":
        if n_train + 2 * n_val > n or n < 4:
            raise ValueError(f"{n} records cannot give {n_train} training and {n_val} validation "
                             "and test records")
        d = np.linalg.norm(pts[:, None, :] - pts[None, :, :], axis=-1)
        np.fill_diagonal(d, np.inf)
        sparse = np.sort(d, axis=1)[:, :3].mean(axis=1)
        ranked = np.lexsort((t, -sparse))  # sparsest first
        val, test = ranked[:n_val], ranked[n_val:2 * n_val]
        train = ranked[::-1][:n_train]
        return np.sort(train), np.sort(val), np.sort(test)
    raise ValueError(f"unknown split {kind!r} (known: {', '.join(SPLITS)})")
