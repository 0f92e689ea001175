"""Campaign summary statistics, from the record store."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from controller.storage.db import CampaignStore


@dataclass(frozen=True)
class ReferenceTruth:
    """What an independent reference knows of one heliostat's run, for scoring the controller:
    a simulated plant's hidden truth, or a survey. Errors are reflected-beam errors, mrad."""

    label: str | None
    error_before_mrad: float | None
    error_after_mrad: float | None


def _stats(values: list[float | None]) -> dict:
    v = [float(x) for x in values if x is not None]
    return {"mean": float(np.mean(v)) if v else None, "max": float(np.max(v)) if v else None}


def summarize(store: CampaignStore, campaign_id: int, *,
              truth: Mapping[str, ReferenceTruth] | None = None) -> dict:
    """The campaign summary over every recorded run (all sessions), from the database.

    Errors are the measured reflected-beam pointing errors, or with ``truth`` (heliostat id ->
    :class:`ReferenceTruth`) the reference's. ``heliostats_per_hour``: *calibrated* heliostats
    per plant hour, from the first run's start to the last run's end (plant clock);
    ``pipelined_speedup``: the sum of every run's own slew-to-standby and target time (what
    one-after-another would take) over that span. ``measured``: runs of a planned night's pass
    that took their one measurement (what a pass is for); ``failed`` counts every run neither
    calibrated nor measured (faults and runs out of iterations).
    """
    runs = store.runs(campaign_id)
    if truth is None:
        before = [r.error_before_mrad for r in runs]
        after = [r.error_after_mrad for r in runs]
    else:
        known = [truth[r.heliostat_id] for r in runs if r.heliostat_id in truth]
        before = [t.error_before_mrad for t in known]
        after = [t.error_after_mrad for t in known]
    camp = store.campaign(campaign_id)
    calibrated = [r for r in runs if r.status == "calibrated"]
    measured = [r for r in runs if r.status == "measured"]
    occ = [r.target_occupancy_s for r in runs if r.target_occupancy_s is not None]
    span = (max(r.end_s for r in runs) - min(r.start_s for r in runs)) if runs else 0.0
    seq = sum(r.sequential_share_s for r in runs)
    return {
        "status": camp.status,
        "cause": camp.cause,
        "heliostats": len(camp.queue),
        "calibrated": len(calibrated),
        "measured": len(measured),
        "failed": len(runs) - len(calibrated) - len(measured),
        "error_before_mrad": _stats(before),
        "error_after_mrad": _stats(after),
        "iterations_mean": float(np.mean([r.iterations for r in runs])) if runs else None,
        "target_occupancy_s_mean": float(np.mean(occ)) if occ else None,
        "heliostats_per_hour": 3600.0 * len(calibrated) / span if span > 0 else None,
        "pipelined_speedup": seq / span if span > 0 else None,
    }


def coarse_summary(store, campaign_id: int, threshold: float | None) -> dict:
    """The coarse correction in the campaign: ``threshold`` (config ``calibration.coarse_correction``),
    ``applied`` (runs with a coarse move), ``iterations_mean`` (measurements per heliostat) over
    all runs, and over the runs with and without a coarse move (``..._runs_with_coarse`` /
    ``..._runs_without_coarse``: different heliostats, not a before/after);
    ``corrections_mean`` (corrective moves per heliostat, each followed by one more capture:
    it counts the looks at a clipped spot, which are not measurements) and ``clipped_first_looks``
    (runs whose first capture showed a spot clipped by the view's edge: a correction before any
    measurement); ``applied_heliostats`` names the runs with a coarse move. The before/after on
    the same heliostats, ``iterations_centroid_only_mean``, is added by :func:`centroid_only_twin`."""
    runs = store.runs(campaign_id)
    moves = {r.id: store.corrections(r.id) for r in runs}
    coarse = {r.id for r in runs if any(c.kind == "coarse" for c in moves[r.id])}

    def mean(rs) -> float | None:
        return round(float(sum(r.iterations for r in rs) / len(rs)), 3) if rs else None

    return {"threshold": threshold, "applied": len(coarse), "iterations_mean": mean(runs),
            "iterations_mean_runs_with_coarse": mean([r for r in runs if r.id in coarse]),
            "iterations_mean_runs_without_coarse": mean([r for r in runs if r.id not in coarse]),
            "applied_heliostats": [r.heliostat_id for r in runs if r.id in coarse],
            "corrections_mean": round(sum(len(m) for m in moves.values()) / len(runs), 3) if runs else None,
            "clipped_first_looks": sum(1 for m in moves.values() if m and m[0].iteration == 0)}
