"""Planned nights: the planner's geometries run as campaigns, one lamp at a time.

A night's plan (:mod:`controller.calibration.night.planner`) lists, per heliostat, a few
(lamp, target, aim point) geometries. They run as ordinary campaigns — the same cycle, target
gate, beam-safe slews and per-heliostat transactions — in *passes*: all of one lamp's
geometries before the next lamp is lit (lamps are switched as rarely as possible), and within
a lamp one pass per target and rank, since a heliostat has one run per campaign. Under one
lamp the targets run in parallel (:func:`controller.calibration.campaign.parallel.run_per_target`),
each its passes in rank order. Each pass is a campaign named ``<night>/<lamp>/<k>`` (one
target) or ``<night>/<lamp>/<k>@<target>`` (several), so a night stopped by ``kill -9``
resumes pass by pass: recorded heliostats are skipped, finished passes are not repeated.
Before each lamp is lit, every heliostat of the night is made safe for it in the dark
(:mod:`controller.calibration.campaign.lamp_change`): a standby pose is safe only for the lamp it was
computed under.
Measurements accumulate in the database across nights and every run refits the heliostat's
model on all of them, weighted by age (``calibration.model.age_halflife_days``).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass

from controller.calibration.beams.slots import lamp_rate
from controller.calibration.campaign.lamp_change import LampChange, Standby
from controller.calibration.campaign.outcome import looked_and_failed
from controller.calibration.campaign.parallel import run_per_target
from controller.calibration.campaign.runner import CampaignResult
from controller.calibration.night.planner import PlanItem, geometry_key
from controller.calibration.records import ModelRecord
from controller.config import PlantConfig


@dataclass(frozen=True)
class Pass:
    """One campaign of a planned night: its ``name``, the ``lamp`` lit, the aim point (m ENU)
    of each heliostat in it and its ``target`` (None: the calibration target)."""

    name: str
    lamp: str
    aims: dict[str, tuple[float, float, float]]
    target: str | None = None


def night_passes(plan: list[PlanItem], night: str) -> list[Pass]:
    """The passes of ``plan`` (module docstring): lamps in order of first appearance, within a
    lamp by target (order of first appearance), then rank."""
    groups: dict[tuple[str, str | None], dict[str, list[PlanItem]]] = {}
    for it in sorted(plan, key=lambda i: (i.heliostat_id, i.rank)):
        key = (it.geometry.lamp, it.geometry.target)
        groups.setdefault(key, {}).setdefault(it.heliostat_id, []).append(it)
    several = len({target for _, target in groups}) > 1
    out = []
    for lamp in dict.fromkeys(lamp for lamp, _ in groups):
        for (lamp_, target), per in groups.items():
            if lamp_ != lamp:
                continue
            for k in range(max(len(v) for v in per.values())):
                aims = {hid: items[k].geometry.aim_enu for hid, items in per.items() if k < len(items)}
                suffix = f"@{target}" if several else ""
                out.append(Pass(f"{night}/{lamp}/{k + 1}{suffix}", lamp, aims, target))
    return out


def lamp_standbys(plan: list[PlanItem], passes: list[Pass], lamp: str) -> dict[str, Standby]:
    """Where each heliostat of ``plan`` waits while ``lamp`` is lit: those in its ``passes``
    beside the aim point of their first pass under it (required), the others beside the
    calibration target if their present pose is unsafe (:class:`lamp_change.Standby`)."""
    out = {it.heliostat_id: Standby() for it in plan}
    for p in passes:
        if p.lamp == lamp:
            for hid, aim in p.aims.items():
                if not out[hid].required:
                    out[hid] = Standby(p.target, aim, required=True)
    return out


def lamps_by_rate(cfg: PlantConfig, models_of: Callable[[list[str]], dict[str, ModelRecord | None]],
                  computing: Callable[[], AbstractContextManager] = nullcontext
                  ) -> Callable[[list[str], list[Pass]], str] | None:
    """``run_night``'s ``next_lamp`` for several beams per target (None for one): the lamp whose
    passes the latest models (``models_of(ids)``) lay out best now
    (:func:`controller.calibration.beams.slots.lamp_rate`). A lamp whose spots are still
    uncertain (fewer slots, more heliostats alone) waits while the other lamps' measurements
    refine its heliostats' models (docs/campaigns.md, "Lamp order"); ties keep the plan's order.
    Evaluated inside ``computing()`` (the plant's clock runs on meanwhile)."""
    k = cfg.calibration.beams_per_target
    if k < 2:
        return None

    def choose(lamps: list[str], passes: list[Pass]) -> str:
        with computing():
            models = models_of(sorted({h for p in passes if p.lamp in lamps for h in p.aims}))
            rate = {lamp: lamp_rate(cfg, lamp, [(p.target or cfg.calibration.target, list(p.aims))
                                                for p in passes if p.lamp == lamp], models, k)
                    for lamp in lamps}
        return max(lamps, key=rate.__getitem__)

    return choose


def run_night(plan: list[PlanItem], night: str, run_pass: Callable[[Pass], CampaignResult],
              stop_all: Callable[[], None] | None = None,
              change_lamp: Callable[[str, dict[str, Standby]], LampChange] | None = None,
              next_lamp: Callable[[list[str], list[Pass]], str] | None = None,
              over: Callable[[], str | None] | None = None) -> list[CampaignResult]:
    """Run every pass of the night with ``run_pass`` (which builds and runs one observing
    campaign: ``CampaignOptions(name=p.name, light_source=p.lamp, aims=p.aims, observe=True,
    target=p.target)``), the targets of a lamp in parallel. A target stops at its first pass
    that did not end ``finished``/``partial`` (aborted, interrupted), the other targets after
    their present pass, and no further lamp is lit. ``stop_all``: asks every running campaign
    to stop (Ctrl-C, :func:`run_per_target`). ``change_lamp(lamp, standbys)``: before each
    lamp's passes, switches every lamp off and makes the night's heliostats safe for ``lamp``
    (a :class:`controller.calibration.campaign.lamp_change.LampChanger`); its LampChangeError ends the
    night with the lamp dark. Without it the caller guarantees that no heliostat of the night
    can reflect the next lamp onto a target (a single-lamp night). ``next_lamp(lamps, passes)``:
    which of the lamps not yet lit comes next (default: in order of first appearance).
    ``over()``: asked before each lamp is lit and each pass starts; a reason (the night's time
    is over: daylight) ends the night there, as a stop would, but the running passes go on to
    their end (they started in time)."""
    results: list[CampaignResult] = []
    halted = threading.Event()
    passes = night_passes(plan, night)
    lamps = list(dict.fromkeys(p.lamp for p in passes))

    def ended() -> bool:
        if not halted.is_set() and over is not None and over() is not None:
            halted.set()
        return halted.is_set()

    while lamps and not ended():
        lamp = next_lamp(lamps, passes) if next_lamp is not None and len(lamps) > 1 else lamps[0]
        lamps.remove(lamp)
        if change_lamp is not None:
            change_lamp(lamp, lamp_standbys(plan, passes, lamp))
        per_target: dict[str | None, list[Pass]] = {}
        for p in passes:
            if p.lamp == lamp:
                per_target.setdefault(p.target, []).append(p)

        def sequence(todo: list[Pass]) -> list[CampaignResult]:
            out = []
            for p in todo:
                if ended():
                    break
                r = run_pass(p)
                out.append(r)
                if r.status not in ("finished", "partial"):
                    halted.set()
            return out

        def stop() -> None:  # Ctrl-C: no further pass starts, the running ones park
            halted.set()
            if stop_all is not None:
                stop_all()

        done = run_per_target({str(t): (lambda todo=todo: sequence(todo)) for t, todo in per_target.items()},
                              stop)
        results += [r for rs in done.values() for r in rs]
        if halted.is_set():
            break
    return results


def failed_geometries(plan: list[PlanItem], p: Pass, r: CampaignResult,
                      calibration_target: str) -> list[dict]:
    """The geometries of pass ``p`` (its result ``r``) whose look failed
    (:func:`controller.calibration.campaign.outcome.looked_and_failed`), as the ``geometry_failures``
    table records them: heliostat, lamp, target, aim grid cell, status, cause."""
    key = {it.heliostat_id: geometry_key(it.geometry, calibration_target) for it in plan
           if it.geometry.lamp == p.lamp and it.geometry.aim_enu == p.aims.get(it.heliostat_id)
           and (it.geometry.target or calibration_target) == (p.target or calibration_target)}
    return [{"heliostat": run.heliostat_id, "lamp": p.lamp, "target": key[run.heliostat_id][1],
             "cell": list(key[run.heliostat_id][2]), "status": run.status, "cause": run.fault_cause}
            for run in r.runs if run.heliostat_id in key and looked_and_failed(run)]


def flagged_keys(flags: list[dict]) -> dict[str, frozenset]:
    """The flagged geometries (``geometry_failures``' flags) per heliostat, as the planner skips
    them (:func:`controller.calibration.night.planner.geometry_key`); a lamp flagged as a whole
    as ``(lamp, None, None)``."""
    out: dict[str, set] = {}
    for g in flags:
        cell = None if g["cell"] is None else tuple(g["cell"])
        out.setdefault(g["heliostat"], set()).add((g["lamp"], g["target"], cell))
    return {hid: frozenset(keys) for hid, keys in out.items()}
