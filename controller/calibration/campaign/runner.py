"""Nightly calibration campaign: the queue, the pipeline and resumption.

A campaign calibrates a list of heliostats against one target under one light source (a
lamp at night). Several targets work in parallel as one campaign each, each with its own
camera, beam chain and gate (:mod:`controller.calibration.campaign.parallel`); slews never cross
another target (:meth:`GeometryPointing.path_to`). It knows only the plant configuration, drives from
:class:`controller.devices.factory.LinkPool`, a :class:`DoubleCcdCamera`, a record store and
an image archive (both handed in by the interface layer); nothing here knows whether the
plant is simulated. What happens is told to :class:`CampaignObserver` s: a terminal progress
bar, a web console, or a simulation harness that keeps its own truth.

* **Queue** (:func:`controller.calibration.campaign.queue_order.order_queue`): heliostats sorted by their
  estimated slew time to their standby point, shortest first (with K beams per target, after
  the first K, by their slew onto the target, longest first). The queue is stored with the
  campaign, so a resumed run keeps it.
* **Pipeline**: up to ``pipeline_depth`` heliostats (K times as many with K beams per target)
  run their cycle at once. Each slews to its standby point in parallel; the :class:`TargetGate`
  then lets them onto the target one at a time, in queue order. So while heliostat k is
  measured, k+1… are already parked at standby.
* **Resumable**: each heliostat's record is committed in one transaction when its cycle ends
  (``store.record_run``). After ``kill -9`` the rerun skips the heliostats already recorded;
  a heliostat interrupted mid-cycle has no record and is calibrated again.
* **Timing** is read from the injected plant ``clock`` (seconds), so throughput is in plant
  time; target occupancy = from the approach command until the beam is parked at standby.
* Measurement chain per capture: :class:`controller.calibration.cycle.beam_chain.BeamChain`.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

from controller.alarms.watch import FieldWatch
from controller.calibration.beams.group import SharedCapture, slot_parks
from controller.calibration.beams.policy import beams_allowed
from controller.calibration.beams.slots import assign_slots, pass_layout, spot_reaches_m
from controller.calibration.campaign.field import Field, LampLit
from controller.calibration.campaign.lamp_change import clear_targets
from controller.calibration.campaign.no_beam import NoBeamWatch, RefusalObserver
from controller.calibration.campaign.observers import CampaignObserver, Observers
from controller.calibration.campaign.outcome import CampaignResult, looked_and_failed, outcome
from controller.calibration.campaign.parallel import campaign_threads
from controller.calibration.campaign.queue_order import order_queue
from controller.calibration.cycle.beam_chain import BeamChain
from controller.calibration.cycle.context import CycleContext, CycleObserver
from controller.calibration.cycle.exposure import capture_unsaturated
from controller.calibration.cycle.gate import TargetGate
from controller.calibration.cycle.machine import STATES, CalibrationCycle
from controller.calibration.cycle.pointing import GeometryPointing
from controller.calibration.cycle.registration_step import register_chain
from controller.calibration.cycle.search import FieldMisses
from controller.calibration.cycle.warm import warm_aims, warm_slews
from controller.calibration.records import (
    CampaignRecord,
    ImageRecord,
    MeasurementRecord,
    ModelRecord,
    RunRecord,
)
from controller.config import PlantConfig
from controller.devices.drive import DriveError
from controller.errors import InputError

INTERRUPTED = "interrupted by the operator"


class RecordStore(Protocol):
    """What the runner needs of the record store (:class:`controller.storage.db.CampaignStore`)."""

    def open_campaign(self, name: str, *, config_path: str, config_sha256: str, light_source: str,
                      target: str, queue: list[str], meta: dict | None = None) -> tuple[int, bool]: ...
    def campaign_by_name(self, name: str) -> CampaignRecord | None: ...
    def done_heliostats(self, campaign_id: int) -> set[str]: ...
    def record_run(self, campaign_id: int, run: RunRecord) -> int: ...
    def finish_campaign(self, campaign_id: int, status: str, cause: str | None = None) -> None: ...
    def update_meta(self, campaign_id: int, meta: dict) -> None: ...
    def runs(self, campaign_id: int) -> list[RunRecord]: ...
    def measurements(self, campaign_id: int | None = None,
                     heliostat_id: str | None = None) -> list[MeasurementRecord]: ...
    def latest_model(self, heliostat_id: str) -> ModelRecord | None: ...
    def latest_models(self, heliostat_ids=None) -> dict[str, ModelRecord]: ...


class ImageSink(Protocol):
    """Keeps the frame pairs of the measurements (:class:`controller.storage.images.ImageArchive`)."""

    def save(self, campaign: str, heliostat_id: str, iteration: int, frame: Any) -> list[ImageRecord]: ...


@dataclass
class CampaignOptions:
    """How one campaign runs. ``None`` takes the configuration's value
    (``calibration.pipeline_depth``, ``calibration.settle_s``, ``calibration.light_source``,
    ``calibration.target``): the configuration is the one source of defaults."""

    name: str = "campaign"
    pipeline_depth: int | None = None
    settle_s: float | None = None
    timeouts: dict[str, float] = field(default_factory=dict)  # per-state overrides, wall s
    move_timeout_s: float = 120.0  # plant seconds
    light_source: str | None = None  # lamp lit for this campaign
    aims: dict[str, tuple[float, float, float]] | None = None  # per-heliostat aim point (planned night)
    observe: bool = False  # planned observations: one measurement each, no correction
    target: str | None = None  # the target of this campaign
    queue_last: tuple[str, ...] = ()  # with several beams: queued last (planning.order_queue)

    def resolved(self, cfg: PlantConfig) -> CampaignOptions:
        """These options with every default taken from ``cfg``."""
        cal = cfg.calibration
        depth = cal.pipeline_depth if self.pipeline_depth is None else self.pipeline_depth
        return replace(self, pipeline_depth=depth,
                       settle_s=cal.settle_s if self.settle_s is None else self.settle_s,
                       light_source=self.light_source or cal.light_source, target=self.target or cal.target)


class Campaign:
    """Runs (or resumes) one campaign on a :class:`controller.calibration.campaign.field.Field`; see
    the module docstring. ``heliostat_ids``: the queue's heliostats (default: the field's
    all); ``meta``: added to the campaign's record; ``observers``: told what happens."""

    def __init__(self, plant: Field, options: CampaignOptions | None = None, *,
                 heliostat_ids: list[str] | None = None, meta: dict | None = None,
                 observers: Sequence[CampaignObserver] = ()) -> None:
        opt = (options or CampaignOptions()).resolved(plant.cfg)
        # A campaign works on one target: it is the calibration target and its camera the camera.
        cfg = plant.cfg.for_target(opt.target)
        if opt.pipeline_depth < 1:
            raise InputError(f"pipeline depth must be at least 1, got {opt.pipeline_depth}")
        self.field = plant
        self.cfg = cfg
        self.opt = opt
        self.store = plant.store
        self.time = plant.time
        self.camera = plant.camera(opt.target)
        self.ids = list(heliostat_ids) if heliostat_ids is not None else [h.id for h in cfg.heliostats]
        for hid in self.ids:
            cfg.heliostat(hid)  # ConfigError naming an unknown id
        self.meta = {**plant.meta, **(meta or {})}
        watch = FieldWatch(plant.alarms, plant.audit, cfg.alarms, opt.target, opt.name, plant.with_models)
        self.observer = Observers([_StateTable(self), watch, *observers])
        self.chain = BeamChain(cfg, plant.library)
        self._camera_lock = threading.Lock()
        self.states: dict[str, str] = {}
        self.lamp: LampLit | None = None  # the light source as lit for this session
        # Stop and pause from another thread (a user interface): request_stop, pause, resume.
        self._stop = threading.Event()
        self._go = threading.Event()
        self._go.set()
        self._cycles: dict[str, CalibrationCycle] = {}
        self.slots = None  # controller.calibration.beams.slots.SlotLayout with several beams per target
        self._tier: dict[str, int] = {}  # each one's slot tier (slots.pass_layout; −1: the target alone)
        self.group: SharedCapture | None = None
        self._current: dict[str, tuple[int, int]] = {}

    def request_stop(self) -> None:
        """Stop the campaign from another thread, as Ctrl-C does: every cycle in flight parks
        its beam (fault path), nothing new starts, and the session is recorded ``interrupted``
        (rerun to resume)."""
        self._stop.set()
        self._go.set()
        for cyc in list(self._cycles.values()):
            cyc.request_abort(INTERRUPTED)

    def pause(self) -> None:
        """No new heliostat starts its cycle until :meth:`resume`; cycles in flight finish."""
        self._go.clear()

    def resume(self) -> None:
        self._go.set()

    # -- devices ------------------------------------------------------------------------------
    def drive(self, hid: str):
        """The drive of ``hid`` (the field's, opened once)."""
        return self.field.drive(hid)

    def _capture(self):
        # A beam core saturated in both sensors merges to lower bounds: shorter exposures first.
        with self._camera_lock:
            return capture_unsaturated(self.camera, bit_depth=self.cfg.camera.bit_depth)

    # -- run ----------------------------------------------------------------------------------
    def run(self) -> CampaignResult:
        cal = self.cfg.calibration
        source = self.cfg.light_source(self.opt.light_source)
        target = self.cfg.target()
        aims = self.opt.aims or {}
        current: dict[str, tuple[int, int]] = {}
        self._current = current  # where each heliostat stands at the start (slots' park check)
        for hid in self.ids:
            try:
                st = self.drive(hid).status()
                current[hid] = (st.az_steps, st.el_steps)
            except DriveError:  # unreachable now: its cycle will record the failure
                pass
        # Several beams per target only under a lamp at night (InputError naming the key otherwise).
        beams = beams_allowed(self.cfg, source.id, self.time.utc())
        misses = FieldMisses()  # what the field already knows: the misses of those found (beam search)
        with self.time.computing():
            models = self.field.models(self.ids)

            def pointing_at(hid: str, aim) -> GeometryPointing:
                return GeometryPointing(self.cfg.heliostat(hid), target, source, self.chain.frame,
                                        cal.standby_offset_m, current.get(hid), cal.model, aim,
                                        others=self.cfg.targets, zones=self.cfg.person_zones,
                                        model=models[hid], search=cal.search, field_misses=misses)

            self._pointing_at = pointing_at
            pointing = {hid: pointing_at(hid, aims.get(hid)) for hid in self.ids}
            warm_aims(pointing.values(), approaches=True)  # standby offsets, steps, approaches: batched
            self.slots, self._tier = None, {}
            if beams > 1:
                # Slots in tiers, each spaced for its spots; the largest take the target alone
                # (slots.pass_layout). The tiers go in turn, most beams first, the alone last.
                reach = spot_reaches_m(self.cfg, target.id, source.id, models, target.center_enu_m)
                layout, member = pass_layout(self.chain.frame, beams, reach, cal.planner.view_margin_m)
                if layout.k > 1:
                    self.slots, self._tier = layout, dict(zip(models, (int(m) for m in member), strict=True))
            existing = self.store.campaign_by_name(self.opt.name)
            k = 1 if self.slots is None else self.slots.k
            alone = sorted(h for h, m in self._tier.items() if m < 0)
            queue = existing.queue if existing is not None else order_queue(
                self.cfg, self.ids, current, pointing, k, (*self.opt.queue_last, *alone), self._tier)
        site = self.cfg.site
        self.meta.setdefault("site", [site.latitude_deg, site.longitude_deg, site.elevation_m])
        self.meta.setdefault("target_normal", list(target.normal))
        # Camera registration (camera.registration) before the campaign opens: refused, nothing is recorded.
        register_chain(self.cfg, self.camera, self.chain, self.observer.fiducial_lamps, self.meta,
                       self._camera_lock, self.time)
        cid, resumed = self.store.open_campaign(
            self.opt.name, config_path=self.field.config_path, config_sha256=self.field.config_sha256,
            light_source=source.id, target=target.id, queue=queue, meta=self.meta)
        try:
            # The queue waits where it stands while the source is lit: no beam may sit on a target.
            clear_targets(pointing, current, self.drive, self.store.latest_model,
                          timeout_s=self.opt.move_timeout_s, time=self.time)
            if source.kind == "lamp":
                # Confirmed lit (a lamp panel) before anything is measured under it; a lamp
                # that does not confirm ends the campaign here, naming it.
                self.lamp = self.field.light(source.id, self.observer.light_source_needed)
            return self._session(cid, resumed, queue, pointing)
        except KeyboardInterrupt:
            self._finish(cid, "interrupted", f"{INTERRUPTED}; rerun the same command to resume")
            raise
        except BaseException as exc:
            # Whatever stopped the campaign (a device gone, a full disk) is its recorded end.
            self._finish(cid, "aborted", f"{type(exc).__name__}: {exc}")
            raise

    def _finish(self, cid: int, status: str, cause: str | None) -> None:
        if self.group is not None:  # several beams: how the captures went (docs/campaigns.md)
            alone = sum(m < 0 for m in self._tier.values())
            self.store.update_meta(cid, {"beams": {"slots": self.slots.k, "rounds": self.group.rounds,
                                                   "measured_alone": self.group.alone,
                                                   "tiers": self.slots.tier_sizes,
                                                   "alone_by_spot_size": alone}})
        self.store.finish_campaign(cid, status, cause)
        self.observer.campaign_finished(cid, status)

    def _session(self, cid: int, resumed: bool, queue: list[str],
                 pointing: dict[str, GeometryPointing]) -> CampaignResult:
        done = self.store.done_heliostats(cid)
        todo = [(i, hid) for i, hid in enumerate(queue) if hid not in done]
        gate = TargetGate()
        self.group = None
        if self.slots is not None:
            # Each heliostat at a slot that suits it; one capture for all beams, identity by a step.
            # Its tier's slots (none: alone, or not in the layout's reckoning: resumed).
            open_ = [self.slots.tier_slots(self._tier.get(h, -1)) for _, h in todo]

            def fits(ticket: int, slot: int) -> bool:
                if (ticket, slot) not in at_slot:  # not the slot it would take if every slot suited
                    at_slot[ticket, slot] = self._pointing_at(todo[ticket][1], self.slots.aim(slot))
                return slot_parks(at_slot[ticket, slot], *self.slots.rank(slot), self.chain.frame,
                                  self._current.get(todo[ticket][1]), self.slots.step_m)

            with self.time.computing():
                at_slot = {(t, s): self._pointing_at(todo[t][1], self.slots.aim(s))
                           for t, s in enumerate(assign_slots(open_, lambda *_: True)) if s is not None}
                warm_aims(at_slot.values(), approaches=True)  # batched: the slot each takes if all suit it
                warm_slews(at_slot.values(), self._current)  # and its slews to standby, as its check asks
                slots = assign_slots(open_, fits)
            for ticket, slot in enumerate(slots):
                if slot is not None:  # else its planned aim, the target to itself (group.py)
                    pointing[todo[ticket][1]] = at_slot[ticket, slot]
            gate = TargetGate(self.slots.k, together=True, slots=slots, conflicts=self.slots.conflicts())
            cal = self.cfg.calibration
            self.group = SharedCapture(gate, self._capture, self.chain.merge, self.chain.frame, self.slots,
                                       cal.identity_settle_s, cal.centroid_threshold)
        t0 = self.time.now()
        session: list[RunRecord] = []
        cycles, stop = self._cycles, self._stop
        watch = NoBeamWatch(self.cfg.light_source(self.opt.light_source).id, self.cfg.target().id, self.lamp)
        observer = RefusalObserver(self.observer, watch, cycles)  # counts refusals early
        self.observer.campaign_started(cid, list(queue), set(done))

        def one(ticket: int, qi: int, hid: str) -> RunRecord | None:
            while not self._go.wait(0.1) and not stop.is_set():
                pass  # paused: this heliostat waits in the queue
            if gate.blocked or stop.is_set():
                gate.release(ticket)
                return None
            with self.time.computing():  # its model and history read from the store
                cyc = CalibrationCycle(self._context(hid, qi, ticket, gate, pointing[hid], observer))
            cycles[hid] = cyc  # registered before the check: a pass that stops later holds it back
            if watch.stopped:  # no beam for several heliostats in a row: the light source is suspect
                cycles.pop(hid, None)
                gate.release(ticket)
                rec = watch.not_measured(hid, qi, self.time.now())
                rec.id = self.store.record_run(cid, rec)
                self.observer.run_recorded(cid, rec)
                return rec
            rec = cyc.run()
            cycles.pop(hid, None)
            if rec.fault_cause == INTERRUPTED:
                return None  # parked, not recorded: a resume calibrates it again
            if gate.blocked and rec.final_state != "aborted" and rec.iterations == 0 \
                    and rec.status == "failed":
                return None  # never reached the target because another beam blocked it: not recorded
            watch.ended(rec)
            if looked_and_failed(rec) and cyc.frame is not None and self.field.images is not None:
                # What the camera saw when it mattered most: kept with the run (run_frames).
                rec.frames = self.field.images.save(self.opt.name, hid, cyc.iteration + 1, cyc.frame)
            with self.time.computing():
                rec.id = self.store.record_run(cid, rec)
            self.observer.run_recorded(cid, rec)
            return rec

        depth = self.opt.pipeline_depth * (1 if self.slots is None else self.slots.k)
        with campaign_threads(self.cfg.calibration.python_one_core), \
                ThreadPoolExecutor(depth, thread_name_prefix="cycle") as pool:
            futures = [pool.submit(one, t, qi, hid) for t, (qi, hid) in enumerate(todo)]
            try:
                for f in futures:
                    rec = f.result()
                    if rec is not None:
                        session.append(rec)
            except KeyboardInterrupt:
                # Ctrl-C / SIGTERM: every cycle in flight parks its beam (fault path), nothing new
                # starts; the caller records the campaign as interrupted.
                stop.set()
                for cyc in list(cycles.values()):
                    cyc.request_abort(INTERRUPTED)
                pool.shutdown(wait=True, cancel_futures=True)
                raise
        t1 = self.time.now()
        runs = self.store.runs(cid)
        status, cause = outcome(runs, queue, gate.blocked, "measured" if self.opt.observe else "calibrated")
        if stop.is_set() and not gate.blocked:  # request_stop: parked, resumable
            status, cause = "interrupted", f"{INTERRUPTED}; start it again to resume"
        self._finish(cid, status, cause)
        return CampaignResult(cid, self.opt.name, resumed, runs, t1 - t0,
                              sum(r.sequential_share_s for r in session), status, cause, len(session))

    def _context(self, hid: str, qi: int, ticket: int, gate: TargetGate,
                 pointing: GeometryPointing, observer: CycleObserver) -> CycleContext:
        cal = self.cfg.calibration
        chain = self.chain
        name = self.opt.name
        images = self.field.images
        h = self.cfg.heliostat(hid)
        timeouts = dict(self.opt.timeouts)
        if self.group is not None:  # capturing waits for the others and may measure again alone
            timeouts.setdefault("capturing", dict((s, t) for s, t, _ in STATES)["standby"])

        def save(frame, hdr, iteration):
            return images.save(name, hid, iteration, frame) if images is not None else []

        return CycleContext(
            heliostat_id=hid, queue_index=qi, ticket=ticket, drive=self.drive(hid),
            camera=_CameraView(self._capture), pointing=pointing,
            merge=chain.merge if self.group is None else self.group.merge,  # a round's frame merged once
            analyze=functools.partial(chain.analyze, allow_clipped=True), match=chain.match, gate=gate,
            model=self.store.latest_model(hid), history=self.store.measurements(heliostat_id=hid),
            tolerance_mrad=cal.tolerance_mrad, max_iterations=1 if self.opt.observe else cal.max_iterations,
            observe_only=self.opt.observe, settle_s=self.opt.settle_s,
            coarse_confidence=None if self.opt.observe else cal.coarse_correction,
            backlash_steps=(h.axes.azimuth.backlash_steps, h.axes.elevation.backlash_steps),
            move_timeout_s=self.opt.move_timeout_s, time=self.time, timeouts=timeouts,
            save_images=save, observer=observer, group=self.group)


class _StateTable(CampaignObserver):
    """Keeps ``Campaign.states`` (heliostat -> current state) for whoever polls it."""

    def __init__(self, campaign: Campaign) -> None:
        self._c = campaign

    def state_changed(self, heliostat_id: str, state: str) -> None:
        self._c.states[heliostat_id] = state


class _CameraView:
    """The shared camera as each cycle sees it (captures serialised by the campaign)."""

    def __init__(self, capture: Callable[[], Any]) -> None:
        self.capture = capture
