"""``heliocal sim field``: a large simulated field with cheap optics, and its night 0 closed loop.

Contract::

    heliocal sim field --out DIR [--heliostats 1000] [--targets 3] [--calibrate N]
                       [--speedup 200] [--night-h 12] [--json]

Builds the field of ``benchmarks/bench_field.py`` (:func:`simplant.cheap_night.field_data` from
the packaged demo plant: ``--heliostats`` on staggered half rings, ``--targets`` stacked on
the tower, six lamps; in-process drives, analytic-spot cameras, on the plant clock at
``--speedup``) in ``DIR`` (``field.yaml``, ``night.db``, ``images/``) and runs its **night 0**:
the product's calibration campaign (``heliocal campaign run``'s, closed loop from the nominal
kinematics, one measurement and correction after another until within tolerance) on ``N``
evenly spread heliostats (default: all), stopped after ``--night-h`` plant hours. The JSON says
how many were calibrated, the plant hours it took and the plant hours the whole field would
take at that rate.

Its Python entry points are what ``benchmarks/bench_field.py`` runs: :func:`night_zero`, the
planned night :func:`run_planned_night`, :func:`seed_from_truth` (the stand-in for a night 0
too long to run closed loop in a benchmark: each heliostat's first capture taken from the plant's
truth), and the truth of "no beam in view but the capture's": :class:`OnTarget`, :func:`strays`.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from controller.calibration.campaign.observers import CampaignObserver
from controller.calibration.campaign.runner import Campaign, CampaignOptions
from controller.calibration.night.planned import calibration_night
from controller.commands._numbers import Number
from controller.commands.cheap_night import calibrate_from_truth as seed_from_truth
from controller.commands.cheap_night import cheap_field, watch_budget
from controller.commands.cheap_night import run_cheap_night as run_planned_night
from controller.commands.common import add_json_option, print_json
from controller.commands.field import open_store
from controller.errors import InputError
from controller.storage.nights import NightBook

__all__ = ["NightZero", "OnTarget", "night_zero", "run_planned_night", "seed_from_truth", "spread", "strays"]


@dataclass
class NightZero:
    """Night 0 on a cheap field: ``heliostats`` calibrated closed loop, how their runs ended
    (``statuses``), their ``measurements``, ``plant_s`` and ``wall_s`` it took."""

    heliostats: int
    statuses: dict[str, int]
    measurements: int
    plant_s: float
    wall_s: float
    stopped_by_budget: bool

    @property
    def calibrated(self) -> int:
        return self.statuses.get("calibrated", 0)


def spread(ids: list[str], n: int) -> list[str]:
    """``n`` of ``ids`` evenly spread (every ring and sector of a field in it); all when n ≥ len."""
    if n >= len(ids):
        return list(ids)
    step = len(ids) / n
    return [ids[int(i * step)] for i in range(n)]


def night_zero(cheap, ids: list[str], name: str, budget_s: float, observers=()) -> NightZero:
    """Night 0 of ``ids`` on ``cheap`` (a :class:`simplant.cheap_night.CheapField`): the product's
    calibration campaign as ``heliocal campaign run`` runs it (:func:`calibration_night`),
    closed loop from whatever models the store holds (none: the nominal kinematics), stopped as
    the console's stop would after ``budget_s`` plant seconds; ``observers`` are told what it does."""
    store = open_store(cheap.db_path)
    done = threading.Event()
    try:
        campaign = Campaign(cheap_field(cheap, store), CampaignOptions(name=name), heliostat_ids=ids,
                            observers=observers)
        t0, wall0 = cheap.time.now(), time.perf_counter()
        watcher, over = watch_budget(cheap, t0 + budget_s, done, campaign.request_stop, "night-0-budget")
        try:
            r = calibration_night(NightBook(store), campaign)
        finally:
            done.set()
            watcher.join()
        plant_s, wall_s = cheap.time.now() - t0, time.perf_counter() - wall0
    finally:
        store.close()
    statuses: dict[str, int] = {}
    for run in r.runs:
        statuses[run.status] = statuses.get(run.status, 0) + 1
    return NightZero(len(ids), statuses, sum(run.iterations for run in r.runs), plant_s, wall_s,
                     over.is_set())


RECENT_CAPTURES = 12  # a measurement's frames are among its target's last few (a round, its identity step)
ELSEWHERE_M = 1.0  # m: a centroid this far from its own beam's true hit is another's spot, or none


class OnTarget(CampaignObserver):
    """Which heliostats the controller means to have on each target now: those whose cycle is
    between its approach and its park (the states from *slewing* to *correcting*, and *fault*
    until parked), on the
    target the plan gives them under the lit lamp (night 0: the calibration target). Each
    cheap camera asks it at every capture (``CheapCamera.expected``); a beam in view that is
    not meant to be there is a stray."""

    STATES = frozenset(("slewing", "settling", "capturing", "merging", "analysing", "matching", "searching",
                        "verifying", "correcting"))
    # Parked (or never out): its beam is off the targets. A cycle that faults on a target keeps
    # its beam there until its fault path has parked it (a frame pair being taken then is still
    # the capture's).
    OFF = frozenset(("idle", "preparing", "standby", "done", "stowed", "aborted"))

    def __init__(self, cheap, plan) -> None:
        self.plant, self.default = cheap.plant, cheap.cfg.calibration.target
        self.where: dict[tuple[str, str], set[str]] = {}
        for it in plan or ():
            key = (it.heliostat_id, it.geometry.lamp)
            self.where.setdefault(key, set()).add(it.geometry.target or self.default)
        self.on: set[str] = set()
        self.state: dict[str, str] = {}  # each heliostat's last state
        self.last_run: dict[str, dict] = {}  # each heliostat's last recorded run, in brief
        self.seen: dict[tuple[str, str], dict] = {}  # (stray heliostat, target): what is known of it
        self.elsewhere: list[dict] = []  # measurements not where their own beam hit (measured())
        self.errors_m: list[float] = []  # each measurement: centroid to its own beam's nearest true hit
        self.cpu_s = 0.0  # thread CPU s of measured(): the benchmark's truth, in the cycles' threads
        self.cameras = cheap.cameras
        self._lock = threading.Lock()  # the targets' cameras capture in their own threads
        for tid, cam in cheap.cameras.items():
            cam.expected = (lambda t=tid: self.meant(t))
            cam.stray_seen = (lambda stray, hits, t=tid: self.note_strays(t, stray, hits))

    def meant(self, target: str) -> set[str]:
        lamp = self.plant.lit
        return {h for h in list(self.on) if target in self.where.get((h, lamp), {self.default})}

    def note_strays(self, target: str, stray, hits: dict) -> None:
        """A capture of ``target`` saw the beams ``stray`` where they were not meant to be (true
        hits ``hits``, m ENU): kept per heliostat and target — how many captures, from and until
        which plant second, under which lamp, the targets its plan gives it under that lamp, the
        states its cycle was in at those captures, where its beam hit first, the steps its rods
        stood at then (the plant's truth) and its last recorded run — so that a record with
        strays says which heliostat, doing what, and where."""
        lamp, now = self.plant.lit, round(float(self.plant.clock()), 1)
        with self._lock:
            for h in stray:
                s = self.seen.get((h, target))
                if s is None:
                    s = self.seen[(h, target)] = {
                        "heliostat": h, "target": target, "lamp": lamp, "captures": 0,
                        "first_plant_s": now, "last_plant_s": now,
                        "meant_targets": sorted(self.where.get((h, lamp), {self.default})), "states": {},
                        "first_hit_enu_m": [round(v, 3) for v in hits[h]],
                        "steps": [int(v) for v in self.plant.hidden[h].controller.output_steps()],
                        "last_run": self.last_run.get(h)}
                s["captures"] += 1
                s["last_plant_s"] = now
                state = self.state.get(h, "not started")
                s["states"][state] = s["states"].get(state, 0) + 1

    def strays_by_heliostat(self, most: int = 20) -> list[dict]:
        """The ``most`` stray heliostats (per target) seen in the most captures, with what
        :meth:`note_strays` kept of each."""
        with self._lock:
            seen = sorted(self.seen.values(), key=lambda s: (-s["captures"], s["heliostat"], s["target"]))
        return seen[:most]

    def measured(self, heliostat_id: str, measurement) -> None:
        """A measurement whose centroid lies more than :data:`ELSEWHERE_M` from every true hit of
        its heliostat's beam in the cameras' last :data:`RECENT_CAPTURES` captures is kept in
        :attr:`elsewhere`, with the heliostat whose true hit in them lies nearest the centroid:
        a spot credited to the wrong beam, whose refit model then solves the park. The
        benchmark's truth, not the controller's work: its CPU is kept in :attr:`cpu_s`."""
        if measurement.centroid_enu is None:
            return
        cpu0 = time.thread_time()
        try:
            self._measured(heliostat_id, measurement)
        finally:
            with self._lock:
                self.cpu_s += time.thread_time() - cpu0

    def _measured(self, heliostat_id: str, measurement) -> None:
        c = tuple(map(float, measurement.centroid_enu))
        own, nearest = math.inf, (math.inf, None)
        for cam in self.cameras.values():
            for hits in cam.hits[-RECENT_CAPTURES:]:
                for hid, p in hits.items():
                    d = math.dist(c, p)  # plain floats: the benchmark's watcher runs in the cycles' threads
                    if hid == heliostat_id:
                        own = min(own, d)
                    elif d < nearest[0]:
                        nearest = (d, hid)
        with self._lock:
            if not math.isinf(own):
                self.errors_m.append(own)
            if own > ELSEWHERE_M:
                self.elsewhere.append({
                    "heliostat": heliostat_id, "plant_s": round(float(measurement.plant_time_s), 1),
                    "own_hit_m": None if math.isinf(own) else round(own, 3), "nearest": nearest[1],
                    "nearest_hit_m": None if math.isinf(nearest[0]) else round(nearest[0], 3)})

    def centroid_errors(self) -> dict:
        """How far each measurement's centroid lay from its own beam's nearest true hit (m, the
        plant's truth; :meth:`measured`): the number of measurements with their beam in view,
        the median, 99th and 99.9th percentiles and the largest (None without any)."""
        with self._lock:
            e = sorted(self.errors_m)
        if not e:
            return {"measurements": 0, "p50": None, "p99": None, "p999": None, "max": None}
        at = lambda q: round(e[min(len(e) - 1, int(q * len(e)))], 4)  # noqa: E731
        return {"measurements": len(e), "p50": at(0.5), "p99": at(0.99), "p999": at(0.999),
                "max": round(e[-1], 4)}

    def run_recorded(self, campaign_id: int, run) -> None:
        self.last_run[run.heliostat_id] = {
            "status": run.status, "cause": (run.fault_cause or "")[:200] or None,
            "fault_state": run.fault_state, "iterations": run.iterations,
            "error_after_mrad": run.error_after_mrad, "end_plant_s": run.end_s}

    def state_changed(self, heliostat_id: str, state: str) -> None:
        self.state[heliostat_id] = state
        if state in self.STATES:
            self.on.add(heliostat_id)
        elif state in self.OFF:
            self.on.discard(heliostat_id)


def strays(cheap, k: int, since: dict[str, int]) -> tuple[int, int, list]:
    """Captures since ``since`` (per camera, a count of captures) with a beam in view that is not
    the capture's (:class:`OnTarget`) or with more than ``k`` beams: (such captures, captures,
    up to five examples)."""
    bad, total, examples = 0, 0, []
    for tid, cam in cheap.cameras.items():
        for i in range(since.get(tid, 0), len(cam.beams_in_view)):
            seen, stray = cam.beams_in_view[i], cam.strays[i] if i < len(cam.strays) else ()
            total += 1
            if stray or len(seen) > k:
                bad += 1
                if len(examples) < 5:
                    examples.append({"target": tid, "in_view": list(seen), "not_the_captures": list(stray)})
    return bad, total, examples


def register(subparsers) -> None:
    p = subparsers.add_parser("field", help="a large simulated field (cheap optics) and its night 0",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the field (created)")
    p.add_argument("--heliostats", type=Number(1, 50_000, integer=True), default=1000, metavar="N")
    p.add_argument("--targets", type=Number(1, 3, integer=True), default=3, metavar="T")
    p.add_argument("--calibrate", type=Number(1, 50_000, integer=True), default=None, metavar="N",
                   help="heliostats calibrated in night 0, evenly spread (default: all)")
    p.add_argument("--speedup", type=Number(0, 1000, lo_open=True), default=200.0, metavar="X",
                   help="plant seconds per wall second (default 200)")
    p.add_argument("--night-h", type=Number(0, 24, lo_open=True), default=12.0, metavar="H",
                   help="night 0 stops after H plant hours (default 12)")
    add_json_option(p)
    p.set_defaults(func=run)


def run(args) -> int:
    import yaml

    from controller.commands.common import PACKAGED_CONFIG, output_dir
    from simplant.cheap_night import CheapField, field_data

    out = output_dir(args.out)  # a folder, or one to create in an existing folder: else refused, named
    if out.exists() and any(out.iterdir()):
        raise InputError(f"--out {out}: not empty; give a new folder")
    data = field_data(yaml.safe_load(Path(PACKAGED_CONFIG).read_text(encoding="utf-8")), int(args.heliostats),
                      int(args.targets))
    cheap = CheapField(data, out, speedup=float(args.speedup))
    ids = [h.id for h in cheap.cfg.heliostats]
    chosen = spread(ids, int(args.calibrate or len(ids)))
    r = night_zero(cheap, chosen, "field/night-0", 3600.0 * float(args.night_h))
    whole_h = r.plant_s / 3600.0 * len(ids) / max(1, r.heliostats)
    result = {"heliostats": len(ids), "calibrated_closed_loop": r.calibrated, "of": r.heliostats,
              "statuses": r.statuses, "measurements": r.measurements, "plant_hours": r.plant_s / 3600.0,
              "whole_field_plant_hours": whole_h, "stopped_by_budget": r.stopped_by_budget,
              "wall_s": r.wall_s, "database": str(cheap.db_path)}
    if args.json:
        print_json(result)
    else:
        print(f"night 0: {r.calibrated} of {r.heliostats} heliostats calibrated closed loop in "
              f"{r.plant_s / 3600:.2f} plant h ({whole_h:.1f} h for all {len(ids)}); {cheap.db_path}")
    return 0
