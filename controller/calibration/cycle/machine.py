"""The calibration state machine of one heliostat (one calibration cycle).

The whole behaviour is the two tables :data:`STATES` (name, timeout, what happens there) and
:data:`TRANSITIONS` (trigger, sources, destination), read by a ``LockedMachine`` shared by every cycle
(:mod:`controller.calibration.cycle.shared_machine`); docs/state-machine.md draws them (tested current).

How it runs (``transitions`` pitfalls in docs/architecture.md): a state's work is a short ``do_<state>``
method returning the next trigger, which :meth:`CalibrationCycle.run` calls *outside* the machine's
lock, then fires. A state's timeout fires ``timeout`` from its own thread (to *fault*); it cannot
interrupt a blocking call, so every wait in a ``do_`` method polls :meth:`_check_current` and gives up
once the machine left that state. An exception in a ``do_`` method fires ``fail``.

Beam safety:
* a heliostat approaches the target only from standby (``preparing`` parks it there first) or
  from a pose as far off every target, whose approach was checked (``Pointing.may_wait_at``);
* :class:`TargetGate` hands the target out in queue order, one beam at a time, back once the beam
  is parked off it (K beams under lamps, each slot once its beam is off: calibration.group);
* after its measurement (or a fault) the beam is moved back to standby before the cycle ends; failing that it
  stays if its beam is off every view, else is stowed; failing that too the cycle ends *aborted*.

Correction (docs/campaigns.md): coarse (:mod:`controller.calibration.cycle.coarse`) or fine (the centroid,
``Pointing.fine_correction``) until within ``tolerance_mrad`` or ``max_iterations`` measurements (one on a
planned observation); then ``Pointing.fit`` refits the model. Measuring moves end moving up on both axes
(``approach``, backlash); a look without a spot goes on to a beam search's next look (``search``).
Units: motor steps (int), degrees at this edge, mrad (reflected beam), ENU m, plant-clock s.
"""

from __future__ import annotations

import functools
import sys

from transitions import MachineError

from controller.calibration.cycle.approach import approach_path
from controller.calibration.cycle.coarse import correction_step
from controller.calibration.cycle.context import CycleContext, CycleObserver
from controller.calibration.cycle.observations import BeamNotFound, NoBeam, Observation
from controller.calibration.cycle.park import STOWED_BESIDE, leave_pose, park, stay_or_stow
from controller.calibration.cycle.search import cycle_search
from controller.calibration.cycle.shared_machine import shared_machine
from controller.calibration.records import CorrectionRecord, RunRecord, measurement_record
from controller.devices.drive import POLL_PAUSE_MAX, DriveError, LinkError, MoveCancelled
from controller.recognition.library import Match

# -- the tables ---------------------------------------------------------------------------------
# (state, timeout in wall s, what it does): bounds for a real field (a full slew at 10 mm/s: ~50 s)
STATES: tuple[tuple[str, float, str], ...] = (
    ("idle", 5.0, "cycle created, nothing commanded"),
    ("preparing", 180.0, "compute the aim (with the fitted model) and park the beam at standby"),
    ("standby", 1800.0, "beam parked off the target: wait for the target, or finish"),
    ("slewing", 120.0, "approach the aim point from standby / apply a correction"),
    ("settling", 10.0, "let the structure settle after the move"),
    ("capturing", 10.0, "capture one double-CCD frame pair"),
    ("merging", 10.0, "merge the pair into one HDR image"),
    ("analysing", 10.0, "beam centroid, Hu moments, pointing error"),
    ("matching", 10.0, "nearest error case in the library (Hu moments)"),
    ("searching", 30.0, "no spot in view: the next beam-safe look of the search pattern"),
    ("verifying", 60.0, "within tolerance or out of iterations? fit the tracking-error model"),
    ("correcting", 10.0, "coarse (library) or fine (centroid Jacobian) correction"),
    ("fault", 180.0, "record the cause, clear faults, park at standby, else stay or stow"),
    ("done", 1.0, "final: beam parked off the target, run recorded"),
    ("stowed", 1.0, "final: standby failed, heliostat stowed"),
    ("aborted", 1.0, "final: could not make the heliostat safe (or aborted by the operator)"),
)
FINAL_STATES = ("done", "stowed", "aborted")
FAULT_ATTEMPTS = 3  # tries to park a faulted heliostat when the link is down
CLIPPED_LOOKS = 2  # corrections towards a spot clipped by the view's edge before giving up
_COMPUTE_STATES = ("merging", "analysing", "matching", "searching", "verifying", "correcting")  # no device
ACTIVE_STATES = tuple(s for s, _, _ in STATES if s not in FINAL_STATES + ("fault",))

TRANSITIONS: tuple[tuple[str, str | tuple[str, ...], str], ...] = (
    # trigger       source(s)                     destination
    ("start",       "idle",                       "preparing"),
    ("parked",      "preparing",                  "standby"),
    ("approach",    "standby",                    "slewing"),
    ("arrived",     "slewing",                    "settling"),
    ("settled",     "settling",                   "capturing"),
    ("captured",    "capturing",                  "merging"),
    ("merged",      "merging",                    "analysing"),
    ("analysed",    "analysing",                  "matching"),
    ("search",      "analysing",                  "searching"),
    ("searched",    "searching",                  "slewing"),
    ("matched",     "matching",                   "verifying"),
    ("correct",     "verifying",                  "correcting"),
    ("corrected",   "correcting",                 "slewing"),
    ("verified",    "verifying",                  "standby"),
    ("release",     "standby",                    "done"),
    ("fail",        ACTIVE_STATES,                "fault"),
    ("timeout",     ACTIVE_STATES + ("fault",),   "fault"),
    ("recovered",   "fault",                      "standby"),
    ("stow",        "fault",                      "stowed"),
    ("give_up",     "fault",                      "aborted"),
    ("abort",       ACTIVE_STATES + ("fault",),   "aborted"),
)


class Cancelled(Exception):
    """The machine left the state while its work was still running (timeout, abort)."""


class CalibrationCycle:
    """Runs one heliostat through :data:`STATES`; :meth:`run` returns its :class:`RunRecord`."""

    def __init__(self, ctx: CycleContext) -> None:
        self.ctx = ctx
        self.machine = shared_machine(STATES, TRANSITIONS, ctx.timeouts)  # this cycle one of its models
        self.machine.add_model(self)
        self._timed_out: str | None = None
        self.iteration = 0
        self.az = self.el = 0
        self.at: tuple[int, int] | None = None  # where the last move ended (None: not known)
        self.aim = self.standby = (0, 0)
        self.beam_on_target = self.holds_target = self.measured = False
        self.status = "running"
        self.cause = self.fault_state = None  # str | None
        self.frame = self.hdr = self.isolate = None  # the frame pair, its HDR image, its own spot (K > 1)
        self.obs: Observation | None = None
        self.match: Match | None = None
        self.coarse_done = False
        self.clipped_looks, self.no_beam = 0, False  # no_beam: a frame held none (status "no_beam")
        self.search, self.missed = cycle_search(ctx), None  # the beam search (None: none), last miss
        self.observer = ctx.observer or CycleObserver()
        now = ctx.time.now()
        self.run_rec = RunRecord(ctx.heliostat_id, ctx.queue_index, "running", "idle", 0, now, now,
                                 search=self.search and self.search.record)

    state: str  # set by transitions

    def _state_changed(self) -> None:
        self.observer.state_changed(self.ctx.heliostat_id, self.state)

    def _on_exception(self, *_event_args) -> None:
        # Called inside the machine's ``except`` block (send_event=False: the trigger's arguments). A
        # trigger no longer valid lost a race with a timeout or abort: the machine already moved on.
        exc = sys.exc_info()[1]
        if not isinstance(exc, MachineError):
            self.cause = self.cause or f"state machine error: {exc!r}"

    def _on_state_timeout(self, state: str) -> None:
        self._timed_out = state
        if self.state == state and state not in FINAL_STATES:
            self.cause = self.cause or f"timeout in state {state}"
            self.fault_state = self.fault_state or state
            self.trigger("timeout")

    def _timeout_is_current(self) -> bool:
        return self._timed_out == self.state

    def _check_current(self, state: str) -> None:
        if self.state != state:
            raise Cancelled(state)

    def request_abort(self, reason: str = "aborted by the operator", *, safe: bool = True) -> None:
        """Stop the cycle from another thread; the running work notices within one poll.

        ``safe``: through *fault*, which parks the beam at standby (or stows); otherwise an
        emergency stop: the drive halts where it is and the cycle ends *aborted*."""
        self.cause = self.cause or reason
        self.fault_state = self.fault_state or self.state
        if safe:
            self.trigger("fail")
            return
        self.trigger("abort")
        try:
            self.ctx.drive.stop()
        except DriveError as exc:  # the stop itself failed: say so in the record
            self.cause = f"{self.cause}; stop failed ({exc})"

    def run(self) -> RunRecord:
        self.trigger("start")
        while self.state not in FINAL_STATES:
            state = self.state
            try:
                if state in _COMPUTE_STATES:
                    with self.ctx.time.computing():
                        nxt = getattr(self, f"do_{state}")()
                else:
                    nxt = getattr(self, f"do_{state}")()
            except Cancelled:
                continue
            except Exception as exc:  # any failure of the work -> fault, with its cause
                if self.state != state:
                    continue
                self.cause = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
                self.fault_state, self.no_beam = state, isinstance(exc, NoBeam)
                if state == "fault":
                    self.trigger("give_up")
                else:
                    self.trigger("fail")
                continue
            if self.state == state:
                self.trigger(nxt)
        return self._finish()

    @property
    def _ticket(self) -> int:
        return self.ctx.queue_index if self.ctx.ticket is None else self.ctx.ticket

    def _wait(self, state: str, seconds: float) -> None:
        """Wait ``seconds`` of plant time, giving up if the machine leaves ``state`` (as a drive wait)."""
        t = self.ctx.time
        end = t.now() + seconds
        while (left := end - t.now()) > 0:
            self._check_current(state)
            t.sleep(min(left, POLL_PAUSE_MAX * t.poll_s))

    def _move(self, state: str, az: int, el: int, watch=None) -> None:
        """Absolute move and wait in position on the plant clock, giving up if the machine
        leaves ``state``; faults raise ActuatorFault/DriveError (controller.devices.drive)."""
        c = self.ctx
        try:
            st = c.drive.move_and_wait(int(az), int(el), timeout_s=c.move_timeout_s, time=c.time,
                                       cancelled=lambda: self.state != state, watch=watch)
        except MoveCancelled:
            raise Cancelled(state) from None
        self.az, self.el = self.at = st.az_steps, st.el_steps

    def do_preparing(self) -> str:
        p, st = self.ctx.pointing, self.ctx.drive.status()
        with self.ctx.time.computing():
            self.aim, self.standby = p.aim_steps(self.ctx.model), p.standby_steps(self.ctx.model)
            # Parked beside the target (a lamp change's standby), it may wait there (may_wait_at).
            here = (st.az_steps, st.el_steps)
            wait = not st.moving and p.may_wait_at(here, self.standby, self.aim, p.path_margin_m())
        if wait:
            self.az, self.el = self.at = here
        else:
            self._park("preparing", status=st)
        self.run_rec.at_standby_s = self.ctx.time.now()
        return "parked"

    def _park(self, state: str, watch=None, status=None) -> None:
        # The slew to standby must not sweep the beam across a target (someone may be measured there)
        # nor into a person zone: waypoints from wherever it stands (after a fault, anywhere).
        park(self.ctx.drive, self.ctx.pointing, self.standby, lambda az, el: self._move(state, az, el, watch),
             status, self.ctx.time.computing)

    def do_standby(self) -> str:
        if self.measured or self.cause:
            if self.beam_on_target:
                if self.ctx.group or self.measured:  # the short way, with what it showed (park.py)
                    with self.ctx.time.computing():
                        self.standby = leave_pose(self)
                self._park("standby", self.ctx.group and self.ctx.group.hand_over(self))
                self.beam_on_target = False
                self.run_rec.off_target_s = self.ctx.time.now()
            self._release_target()
            return "release"
        if not self.ctx.gate.acquire(self._ticket, lambda: self.state != "standby"):
            self._check_current("standby")
            raise RuntimeError("target blocked: another heliostat's beam may still be on it")
        self.holds_target = True
        self.az, self.el = self.search.first_pose(self.aim) if self.search else self.aim
        return "approach"

    def do_slewing(self) -> str:
        if not self.beam_on_target:
            self.run_rec.on_target_s = self.ctx.time.now()
        self.beam_on_target = True  # from the first command on, the beam may cross the target
        lim = self.ctx.drive.limits
        for waypoint in approach_path(self.at, (self.az, self.el), self.ctx.backlash_steps, lim):
            self._move("slewing", *waypoint)
        return "arrived"

    def do_settling(self) -> str:
        self._wait("settling", self.ctx.settle_s)
        return "settled"

    def do_capturing(self) -> str:
        if self.ctx.group is None:
            self.frame = self.ctx.camera.capture()
        else:  # several beams on the target: one capture for all, whose spot confirmed by a step
            self.frame, self.isolate = self.ctx.group.capture(self)
        return "captured"

    def do_merging(self) -> str:
        self.hdr = self.ctx.merge(self.frame)
        return "merged"

    def do_analysing(self) -> str:
        iso = self.isolate  # several beams: its own spot only, centred where its cell's energy lies
        try:
            self.obs = self.ctx.analyze(self.hdr if iso is None else iso(self.hdr))  # BeamNotFound: why
            self.obs = self.obs if iso is None else iso.measured(self.obs)
        except BeamNotFound as exc:
            if self.search is None or self.search.record.found:
                raise
            self.missed = exc
            return "search"
        return self.search.seen(self.obs.centroid_enu, self.ctx.time.now()) if self.search else "analysed"

    def do_searching(self) -> str:
        self.az, self.el = self.search.next_look(self.at, self.ctx.time.now(), self.missed)  # NoBeam: spent
        return "searched"

    def do_matching(self) -> str:
        self.match = self.ctx.match(self.obs)
        return "matched"

    def do_verifying(self) -> str:
        p, obs, m = self.ctx.pointing, self.obs, self.match
        if obs.clipped:  # not a measurement: move towards the visible part and look again
            self.clipped_looks += 1
            if self.clipped_looks > CLIPPED_LOOKS:
                raise BeamNotFound(f"beam spot clipped by the {'/'.join(obs.clipped)} edge of the camera "
                                   f"view after {CLIPPED_LOOKS} corrections towards it")
            return "correct"
        self.iteration += 1
        rec = measurement_record(p, obs, m, self.iteration, (self.az, self.el), self.ctx.time.now(),
                                 self.ctx.time.utc())
        err = rec.error_mrad
        if self.ctx.save_images is not None:
            rec.images = self.ctx.save_images(self.frame, self.hdr, self.iteration)
        self.observer.measured(self.ctx.heliostat_id, rec)
        self.run_rec.measurements.append(rec)
        if self.iteration == 1:
            self.run_rec.error_before_mrad = err
            self.run_rec.matched_label = "unknown" if m is not None and m.unknown else rec.matched_label
        self.run_rec.error_after_mrad = err
        self.run_rec.iterations = self.iteration
        done = err <= self.ctx.tolerance_mrad or self.iteration >= self.ctx.max_iterations
        if self.ctx.observe_only or done:
            if self.ctx.observe_only:
                self.status = "measured"
            else:
                self.status = "calibrated" if err <= self.ctx.tolerance_mrad else "not_converged"
            self.measured = True
            self.run_rec.model = p.fit(self.ctx.history + self.run_rec.measurements, self.ctx.model)
            return "verified"
        return "correct"

    def do_correcting(self) -> str:
        c = self.ctx
        kind, step = correction_step(c.pointing, self.az, self.el, self.obs, self.match, run=self.run_rec,
                                     first=not self.coarse_done, min_confidence=c.coarse_confidence)
        self.coarse_done = True
        self.run_rec.corrections.append(CorrectionRecord(self.iteration, kind, step.daz_deg, step.del_deg,
                                                         step.daz_steps, step.del_steps))
        lim = self.ctx.drive.limits
        self.az = min(max(self.az + step.daz_steps, lim.az.min_steps), lim.az.max_steps)
        self.el = min(max(self.el + step.del_steps, lim.el.min_steps), lim.el.max_steps)
        return "corrected"

    def do_fault(self) -> str:
        """Make the heliostat safe: clear latched faults, park at standby, else :func:`stay_or_stow`."""
        d = self.ctx.drive
        self.status, first = "failed", None  # first: the first exception (Exception | None)
        for attempt in range(FAULT_ATTEMPTS):  # a dropped link may come back (reconnect): a second apart
            try:
                d.clear_fault()
                if self.standby == (0, 0):
                    self.standby = self.ctx.pointing.standby_steps(self.ctx.model)
                self._park("fault")
                first = None  # parked after all
                break
            except Cancelled:
                raise
            except LinkError as exc:
                first = exc
                if attempt + 1 < FAULT_ATTEMPTS:
                    self._wait("fault", 1.0)
            except Exception as exc:  # not a link problem, or no safe path: retrying will not help
                first = exc
                break
        try:  # the firmware's stow is not a beam-safe path: only where the beam is not safe already
            done = "parked" if first is None else stay_or_stow(d, self.ctx.pointing, self.ctx.move_timeout_s,
                                                                self.ctx.time)
            self.cause = self.cause if first is None else f"{self.cause}; standby failed ({first}), {done}"
            self.beam_on_target = done == STOWED_BESIDE  # then it keeps everyone off the target
            if done in ("parked", "stayed"):
                self.run_rec.off_target_s = self.ctx.time.now() if self.holds_target else None
                return "recovered"
            self._release_target()
            return "stow"
        except Exception as second:
            self.cause = f"{self.cause}; standby failed ({first}); stow failed ({second})"
            return "give_up"

    def _release_target(self) -> None:
        self.ctx.gate.release(self._ticket, beam_off_target=not self.beam_on_target)
        self.holds_target = False

    def _finish(self) -> RunRecord:
        if self.state == "aborted":
            # Whatever happened, the ticket is given back; a beam possibly left on the target
            # blocks the gate for everyone after.
            self.ctx.gate.release(self._ticket, beam_off_target=not self.beam_on_target)
        if self.cause:
            self.status = "no_beam" if self.no_beam and self.state != "aborted" else "failed"
        r = self.run_rec
        r.status, r.final_state, r.fault_cause = self.status, self.state, self.cause
        r.fault_state, r.end_s = self.fault_state, self.ctx.time.now()
        self.machine.remove_model(self)
        return r


for _state, _, _ in STATES:  # the shared machine's on_timeout of each state (shared_machine.py)
    setattr(CalibrationCycle, f"_timeout_{_state}",
            functools.partialmethod(CalibrationCycle._on_state_timeout, _state))
