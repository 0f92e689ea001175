"""Planned nights: the planner's geometries run as campaigns, one lamp at a time.

A night's plan (:mod:`controller.calibration.planner`) lists, per heliostat, a few
(lamp, aim point) geometries. They run as ordinary campaigns — the same cycle, target gate,
beam-safe slews and per-heliostat transactions — in *passes*: all of one lamp's geometries
before the next lamp is lit (lamps are switched as rarely as possible), and within a lamp
one pass per rank, since a heliostat has one run per campaign. Each pass is a campaign named
``<night>/<lamp>/<k>``, so a night stopped by ``kill -9`` resumes pass by pass: recorded
heliostats are skipped, finished passes are not repeated. Measurements accumulate in the
database across nights and every run refits the heliostat's model on all of them, weighted
by age (``calibration.model.age_halflife_days``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from controller.calibration.planner import PlanItem
from controller.calibration.runner import CampaignResult


@dataclass(frozen=True)
class Pass:
    """One campaign of a planned night: its ``name``, the ``lamp`` lit, and the aim point
    (m ENU) of each heliostat in it."""

    name: str
    lamp: str
    aims: dict[str, tuple[float, float, float]]


def night_passes(plan: list[PlanItem], night: str) -> list[Pass]:
    """The passes of ``plan`` (module docstring), lamps in order of first appearance."""
    lamps: dict[str, dict[str, list[PlanItem]]] = {}
    for it in sorted(plan, key=lambda i: (i.heliostat_id, i.rank)):
        lamps.setdefault(it.geometry.lamp, {}).setdefault(it.heliostat_id, []).append(it)
    out = []
    for lamp, per in lamps.items():
        for k in range(max(len(v) for v in per.values())):
            aims = {hid: items[k].geometry.aim_enu for hid, items in per.items() if k < len(items)}
            out.append(Pass(f"{night}/{lamp}/{k + 1}", lamp, aims))
    return out


def run_night(plan: list[PlanItem], night: str,
              run_pass: Callable[[Pass], CampaignResult]) -> list[CampaignResult]:
    """Run every pass of the night with ``run_pass`` (which builds and runs one observing
    campaign: ``CampaignOptions(name=p.name, light_source=p.lamp, aims=p.aims, observe=True)``).
    Stops at the first pass that did not end ``finished``/``partial`` (aborted, interrupted)."""
    results = []
    for p in night_passes(plan, night):
        r = run_pass(p)
        results.append(r)
        if r.status not in ("finished", "partial"):
            break
    return results
