"""A planned night on a field: the operation behind ``heliocal campaign night``, the console's
night and ``heliocal demo``.

On a :class:`controller.calibration.campaign.field.Field` (real or simulated, it cannot tell):

1. open (or resume) the night's record (:class:`NightStore`, the ``nights`` table);
2. unless a plan is already stored for it, measure every heliostat that has no model yet at
   the calibration lamp first (a closed-loop campaign ``<night>/calibration``: the planner
   needs a model to plan from);
3. plan from the models in the store (:func:`controller.calibration.night.planner.plan_night`), or
   reload the plan stored for this night when it is resumed;
4. run the passes (:func:`controller.calibration.night.passes.run_night`): lamps changed in the dark
   (:class:`controller.calibration.campaign.lamp_change.LampChanger`), the targets of a lamp in
   parallel, each pass a :class:`controller.calibration.campaign.runner.Campaign` whose every run
   refits its heliostat's model; each lamp is confirmed lit before anything is measured under it;
5. record and return the night's :class:`NightSummary`.

A rerun after Ctrl-C or ``kill -9`` resumes the same night: its plan is stored, finished
passes are not repeated and recorded heliostats are skipped. Ctrl-C parks every beam
(each campaign's fault path) and, when the field has a lamp panel, leaves every lamp off.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from typing import Protocol

from controller.alarms.watch import night_ended
from controller.calibration.beams.policy import night_over
from controller.calibration.campaign.field import Field, LampEnd
from controller.calibration.campaign.lamp_change import LampChange, LampChangeError, LampChanger, Standby
from controller.calibration.campaign.lights_out import lights_out_at_end, not_dark_message, require_dark
from controller.calibration.campaign.observers import Observers
from controller.calibration.campaign.runner import Campaign, CampaignObserver, CampaignOptions, CampaignResult
from controller.calibration.night.daytime import DaytimeTally, predicted_daytime, sun_path
from controller.calibration.night.passes import (
    Pass,
    failed_geometries,
    flagged_keys,
    lamps_by_rate,
    run_night,
)
from controller.calibration.night.planner import PlanItem, check_plan, plan_field
from controller.calibration.night.summary import NightSummary, night_status
from controller.calibration.records import NightRecord
from controller.config import PlantConfig
from controller.errors import HeliocalError

STRATEGIES = ("design", "round-robin")


class NightStore(Protocol):
    """What a night keeps besides its campaigns (:class:`controller.storage.nights.NightBook`)."""

    def open_night(self, name: str, kind: str) -> tuple[NightRecord, bool]: ...
    def finish_night(self, night_id: int, status: str, cause: str | None, summary: dict) -> None: ...
    def unfinished(self, kind: str = "planned") -> NightRecord | None: ...
    def next_index(self) -> int: ...
    def plan(self, night: str) -> list[PlanItem]: ...
    def record_plan(self, items: list[PlanItem]) -> None: ...
    def add_to_summary(self, name: str, extra: dict) -> None: ...
    def record_heliostats(self, night_id: int, rows: list[dict]) -> None: ...
    def record_lamp_states(self, session: str, ended: str, lamps: list[LampEnd]) -> None: ...
    def record_field(self, cfg: PlantConfig, ids: list[str], config_path: str, sha256: str) -> None: ...
    def measured(self, night: str) -> dict[str, int]: ...
    def record_geometry_failures(self, night: str, failures: list[dict]) -> None: ...
    def flagged(self, ids: list[str] | None = None) -> list[dict]: ...


def calibration_night(book: NightStore, campaign: Campaign) -> CampaignResult:
    """Run ``campaign`` (a closed-loop calibration campaign) as a night of its own: night 0 of a
    new field, the next index otherwise; its record says how it ended. However it ends, every
    lamp is switched off and confirmed dark, and recorded
    (:mod:`controller.calibration.campaign.lights_out`)."""
    name = campaign.opt.name
    rec, resumed = book.open_night(name, "calibration")
    plant = campaign.field

    def lights_out(ended: str, cause: str | None) -> list[LampEnd]:
        lit = [campaign.lamp.lamp] if campaign.lamp else []
        try:
            return lights_out_at_end(plant, book, name, ended, campaign.observer, lit=lit)
        except BaseException as exc:  # the record says so: it never stays running
            _finish_failed(book, rec, ended, cause, exc)
            raise

    try:
        plant.audit.record("night.resume" if resumed else "night.start", name, "calibration campaign")
        book.record_field(plant.cfg, campaign.ids, plant.config_path, plant.config_sha256)
        r = campaign.run()
    except BaseException as exc:
        status, cause = _ended_by(exc)
        ends = lights_out(status, cause)
        book.finish_night(rec.id, status, _with_lamps(cause, name, ends),
                          {"lights_out": [e.to_json() for e in ends]})
        plant.audit.record("night.end", name, status + (f": {cause}" if cause else ""))
        require_dark(name, ends, after=exc)
        raise
    ends = lights_out(r.status, r.cause)
    lamps = [campaign.lamp.to_json()] if campaign.lamp else []
    book.finish_night(rec.id, r.status, _with_lamps(r.cause, name, ends),
                      {"campaign": r.name, "status": r.status, "lamps": lamps,
                       "lights_out": [e.to_json() for e in ends]})
    plant.audit.record("night.end", name, r.status + (f": {r.cause}" if r.cause else ""))
    require_dark(name, ends)
    return r


def _ended_by(exc: BaseException) -> tuple[str, str]:
    """The status and cause a night records when ``exc`` stopped it: Ctrl-C (SIGTERM) or another."""
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted", "interrupted by the operator; rerun to resume"
    return "aborted", f"{type(exc).__name__}: {exc}"


def _finish_failed(book: NightStore, rec: NightRecord, status: str, cause: str | None,
                   exc: BaseException) -> None:
    """Night ``rec`` could not be ended as it should (``exc`` while switching the lamps off or
    summing it up): recorded ``aborted`` (``interrupted`` for a second Ctrl-C) with the cause
    and why, so that it never stays ``running``."""
    why = f"ending it failed: {_ended_by(exc)[1]}"
    ended = "interrupted" if status == "interrupted" or isinstance(exc, KeyboardInterrupt) else "aborted"
    book.finish_night(rec.id, ended, "; ".join(x for x in (cause, why) if x), rec.summary)


def _with_lamps(cause: str | None, session: str, ends: list[LampEnd]) -> str | None:
    """A night's cause with the lamps it left not confirmed dark, if any."""
    line = not_dark_message(session, ends)
    return "; ".join(x for x in (cause, line) if x) or None


def tonight(book: NightStore, base: str) -> tuple[str, int]:
    """The name and index of tonight's planned night: the unfinished one to resume, else
    ``<base>/night-<k>`` with the next index ``k``."""
    open_ = book.unfinished("planned")
    if open_ is not None:
        return open_.name, open_.index
    k = book.next_index()
    return f"{base}/night-{k}", k


class PlannedNight:
    """Runs (or resumes) planned night ``name`` (index ``index``) on ``plant`` (module
    docstring). ``heliostat_ids``: tonight's heliostats (default all); ``strategy``: the
    planner's (:data:`STRATEGIES`); ``observers``: handed to every campaign of the night;
    ``progress(text)``: told of each pass and how far the night is; ``workers``: processes
    that plan the field and predict its daytime error (None: one per core for a large field)."""

    def __init__(self, plant: Field, book: NightStore, name: str, index: int, *,
                 heliostat_ids: list[str] | None = None, strategy: str = "design",
                 observers: Sequence[CampaignObserver] = (), progress: Callable[[str], None] | None = None,
                 ask_operator: Callable[[], None] | None = None, workers: int | None = None) -> None:
        if strategy not in STRATEGIES:
            raise ValueError(f"planner strategy must be one of {STRATEGIES}, got {strategy!r}")
        self.field = plant
        self.book = book
        self.name = name
        self.index = index
        self.ids = list(heliostat_ids) if heliostat_ids is not None else [h.id for h in plant.cfg.heliostats]
        self.strategy = strategy
        self.observers = list(observers)
        self.progress = progress or (lambda text: None)
        self._watched = progress is not None  # someone follows the night: tell them the field's state
        self.changer = LampChanger(plant, lights_out=None if plant.lamps is not None else ask_operator)
        self.ask_operator = ask_operator
        self.path = sun_path(plant.cfg.site)
        self._lock = threading.Lock()
        self._live: set[Campaign] = set()
        self._stopped = threading.Event()
        self.plan: list[PlanItem] = []
        self.unmeasurable: list[dict] = []
        self.workers = workers
        self.tally = DaytimeTally(plant.cfg, self.path)
        self.results: list[CampaignResult] = []  # every campaign of this session, as they end
        self.lamps: dict[str, dict] = {}
        self.changes: list[LampChange] = []
        self.measured: set[str] = set()  # "<pass>/<heliostat>" measured tonight
        self.alone: set[str] = set()  # heliostats whose spot had to be measured alone tonight (K > 1)
        self.state: dict = {"pass": None, "lamp": None, "daytime_error_predicted_rms": None}
        self.daylight: str | None = None  # why the night's time ended before its plan (night_over)

    # -- control from another thread (Ctrl-C's path, the console) -----------------------------------
    def request_stop(self) -> None:
        """Stop the night: no further pass starts, every running campaign parks its beams and
        records itself interrupted; rerun to resume."""
        self._stopped.set()
        with self._lock:
            for c in list(self._live):
                c.request_stop()

    def snapshot(self) -> dict:
        """Where the night stands: the pass and lamp now, geometries measured of those planned."""
        with self._lock:
            return {"night": self.index, "name": self.name, **self.state, "planned": len(self.plan),
                    "measured": len(self.measured), "heliostats_measured": len({m.rsplit("/", 1)[1]
                                                                                for m in self.measured})}

    # -- the night -------------------------------------------------------------------------------
    def run(self) -> NightSummary:
        rec, resumed = self.book.open_night(self.name, "planned")
        f = self.field
        results: list[CampaignResult] = []
        first: list[str] = []
        try:
            f.audit.record("night.resume" if resumed else "night.start", self.name,
                           f"{len(self.ids)} heliostat(s)")
            self.book.record_field(f.cfg, self.ids, f.config_path, f.config_sha256)  # what the models rest on
            # A stored plan (a resumed night, or one handed in) is run as it is, when it still
            # fits the configuration; a new night first measures the heliostats the planner has
            # no model of.
            stored = self.book.plan(self.name)
            check_plan(stored, f.cfg, f.config_path)
            if stored:  # resumed: why some heliostats had no measurable geometry was said when it was planned
                self.unmeasurable = list(rec.summary.get("unmeasurable", []))
            first, calib = ([], []) if stored else self._calibrate_new()
            results += calib
            if all(r.status in ("finished", "partial") for r in calib) and not self._stopped.is_set():
                self.plan = self._plan()
                self.progress(f"{self.name}: {len(self.plan)} geometries planned for "
                              f"{len({i.heliostat_id for i in self.plan})} heliostats")
                results += run_night(self.plan, self.name, self._run_pass, self.request_stop,
                                     self._change_lamp, lamps_by_rate(f.cfg, f.models, f.time.computing),
                                     self._over)
        except LampChangeError as exc:
            return self._end(rec, results, first, "aborted", str(exc))
        except BaseException as exc:  # Ctrl-C, or whatever else stopped it: recorded, lights out
            self._end(rec, results, first, *_ended_by(exc), exc)
            raise
        status, cause = night_status(results, self._stopped.is_set(), self.daylight)
        return self._end(rec, results, first, status, cause)

    def _calibrate_new(self) -> tuple[list[str], list[CampaignResult]]:
        """Heliostats without a model: one closed-loop campaign at the calibration lamp first."""
        have = self.field.with_models(self.ids)
        new = [hid for hid in self.ids if hid not in have]
        if not new:
            return [], []
        lamp = self.field.cfg.calibration.light_source
        self.progress(f"{self.name}: {len(new)} heliostat(s) without a model, measured at {lamp} first")
        standby = {hid: Standby(required=hid in new) for hid in self.ids}
        if self.field.cfg.light_source(lamp).kind == "lamp":
            self._change_lamp(lamp, standby)
        r = self._campaign(CampaignOptions(name=f"{self.name}/calibration"), new)
        return new, [r]

    def _plan(self) -> list[PlanItem]:
        plan = self.book.plan(self.name)
        if not plan:
            flags = self.book.flagged(self.ids)  # failed on two nights: not planned until cleared
            if flags:
                self.progress(f"{self.name}: {len(flags)} flagged geometr{'y' if len(flags) == 1 else 'ies'} "
                              "not planned (each failed on two nights; heliocal campaign flags)")
            with self.field.time.computing():
                done = plan_field(self.field.cfg, self.field.models(self.ids), self.name,
                                  strategy=self.strategy, night_index=self.index, workers=self.workers,
                                  flagged=flagged_keys(flags))
            plan = done.items
            self.unmeasurable = [u.to_json() for u in done.unmeasurable]
            self.book.record_plan(plan)
            self.book.add_to_summary(self.name, {"unmeasurable": self.unmeasurable})
            if self.unmeasurable:
                first = self.unmeasurable[0]
                self.progress(f"{self.name}: {len(self.unmeasurable)} heliostat(s) with no measurable "
                              f"geometry tonight, e.g. {first['heliostat']}: {first['why']}")
        return plan

    def _over(self) -> str | None:
        """Why no further lamp is lit and no further pass starts (the sun is up: :func:`night_over`)."""
        self.daylight = self.daylight or night_over(self.field.cfg, self.field.time.utc())
        return self.daylight

    def _change_lamp(self, lamp: str, standbys: dict[str, Standby]) -> LampChange:
        self.state["lamp"] = lamp
        # Every heliostat of the night is made safe for the lamp, those without a geometry
        # tonight too: their beams under it must not reach a target either.
        standbys = {**{hid: Standby() for hid in self.ids}, **standbys}
        done = self.changer(lamp, standbys)
        self.changes.append(done)
        self.progress(f"{self.name}: {lamp}: {len(done.parked)} heliostat(s) moved to its standby, "
                      f"{len(done.stowed)} stowed, in the dark")
        return done

    def _run_pass(self, p: Pass) -> CampaignResult:
        self.state["pass"] = p.name
        self.progress(f"{p.name}: {len(p.aims)} heliostat(s) under {p.lamp}"
                      + (f" on {p.target}" if p.target else ""))
        with self._lock:  # with several beams, a spot measured alone before goes last (runner.py)
            last = tuple(sorted(self.alone & p.aims.keys()))
        r = self._campaign(CampaignOptions(name=p.name, light_source=p.lamp, aims=p.aims, observe=True,
                                           target=p.target, queue_last=last), list(p.aims))
        with self._lock:
            self.measured |= {f"{p.name}/{run.heliostat_id}" for run in r.runs if run.status == "measured"}
        self.book.record_geometry_failures(self.name, failed_geometries(self.plan, p, r,
                                                                        self.field.cfg.calibration.target))
        if self._watched:
            # The operator's view of the field as the night goes: the controller's own computing,
            # for the heliostats whose models changed (the whole field the first time).
            with self.field.time.computing():
                changed = self.ids if not self.tally.sums else [run.heliostat_id for run in r.runs]
                self.tally.update(self.field.models(changed))
            self.state["daytime_error_predicted_rms"] = self.tally.rms
            self.progress(f"{self.name}: {len(self.measured)}/{len(self.plan)} geometries measured; "
                          f"field predicted daytime RMS {self.tally.rms:.2f} mrad")
        return r

    def _campaign(self, options: CampaignOptions, ids: list[str]) -> CampaignResult:
        c = Campaign(self.field, options, heliostat_ids=ids, observers=self.observers)
        with self._lock:
            self._live.add(c)
            if self._stopped.is_set():  # stopped meanwhile: the campaign records itself interrupted
                c.request_stop()
        try:
            r = c.run()
        except HeliocalError as exc:
            # A device that failed the whole campaign (a lamp that did not confirm, a camera gone):
            # recorded aborted by the campaign; the night stops its passes with this cause.
            rec = self.field.store.campaign_by_name(options.name)
            r = CampaignResult(rec.id if rec else -1, options.name, False,
                               self.field.store.runs(rec.id) if rec else [], 0.0, 0.0, "aborted", str(exc))
        finally:
            with self._lock:
                self._live.discard(c)
        with self._lock:
            self.results.append(r)
            self.alone |= set(c.group.alone if c.group is not None else ())
        if c.lamp is not None and c.lamp.lamp not in self.lamps:
            self.lamps[c.lamp.lamp] = c.lamp.to_json()
        return r

    def _end(self, rec: NightRecord, results: list[CampaignResult], first: list[str], status: str,
             cause: str | None, after: BaseException | None = None) -> NightSummary:
        """Lights out (every end: :mod:`controller.calibration.campaign.lights_out`), then the night's
        record; :class:`LampNotDark` after it when a lamp is not confirmed dark. The record is
        finished on every path: when ending the night fails itself, it says so in the cause."""
        try:
            s, ends, per_heliostat = self._summary(rec, results, first, status, cause)
        except BaseException as exc:
            _finish_failed(self.book, rec, status, cause, exc)
            raise
        self.book.finish_night(rec.id, s.status, s.cause, s.to_json())
        night_ended(self.field, self.name, s.status, s.cause, per_heliostat, self.ids)
        self.progress(f"{self.name}: {s.status}; {s.measured}/{len(self.plan)} geometries measured; "
                      f"field predicted daytime RMS {s.daytime_error_predicted_mrad['rms']:.2f} mrad")
        require_dark(self.name, ends, after)
        return s

    def _summary(self, rec: NightRecord, results: list[CampaignResult], first: list[str], status: str,
                 cause: str | None) -> tuple[NightSummary, list[LampEnd], dict[str, float]]:
        """Lights out, then the night's summary, its lamps' end states and each heliostat's
        predicted daytime RMS (recorded in ``night_heliostats``)."""
        ends = lights_out_at_end(self.field, self.book, self.name, status, Observers(self.observers),
                                 lit=self.lamps, ask_operator=self.ask_operator)
        cause = _with_lamps(cause, self.name, ends)
        # From the store: a pass stopped by Ctrl-C returned no result, but its runs are recorded.
        per = self.book.measured(self.name)
        measured = sum(per.values())
        with self.field.time.computing():
            now = predicted_daytime(self.field.cfg, self.field.models(self.ids), self.path,
                                    workers=self.workers)
        self.book.record_heliostats(rec.id, self._heliostat_rows(per, now.per_heliostat))
        s = NightSummary(self.index, self.name, len(self.ids), len(self.plan), measured,
                         len(self.plan) - measured,
                         list(self.lamps.values()), now.to_json(),
                         status, cause, first,
                         [{"name": r.name, "status": r.status, "cause": r.cause,
                           "measured": sum(run.status in ("measured", "calibrated") for run in r.runs),
                           "heliostats": len(r.runs)} for r in results],
                         [c.to_json() for c in self.changes], self.unmeasurable, [e.to_json() for e in ends],
                         self.book.flagged(self.ids))
        return s, ends, now.per_heliostat

    def _heliostat_rows(self, measured: dict[str, int], predicted: dict[str, float]) -> list[dict]:
        """What each heliostat of the night ended with (the ``night_heliostats`` table): where
        it stands, its geometries planned and measured tonight, its predicted daytime RMS and,
        when it had none measurable, why."""
        planned: dict[str, int] = {}
        for it in self.plan:
            planned[it.heliostat_id] = planned.get(it.heliostat_id, 0) + 1
        why = {u["heliostat"]: u["why"] for u in self.unmeasurable}
        out = []
        for hid in self.ids:
            e, n, _ = self.field.cfg.heliostat(hid).position_enu_m
            out.append({"heliostat": hid, "east_m": float(e), "north_m": float(n),
                        "planned": planned.get(hid, 0), "measured": measured.get(hid, 0),
                        "predicted_rms_mrad": predicted.get(hid), "unmeasurable": why.get(hid)})
        return out
