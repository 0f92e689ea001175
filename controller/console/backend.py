"""What the console drives: the heliostats' drives, the camera, commissioning sessions, the
campaign lock and the drive-status poller that feeds the live page.

Safety rules (docs/console.md), enforced here for every request, whatever page sent it:

* every move goes through :class:`controller.calibration.cycle.commissioning.Commissioning`, i.e.
  ``Drive.move_and_wait`` (soft limits checked by the controller before sending; firmware
  refusals raised as :class:`NakError` and shown);
* while a campaign runs, its state machine owns the heliostats and the camera: no manual
  command is accepted (:class:`Conflict`);
* one beam per target: a heliostat whose session may have put its beam on the target (it was
  moved and not parked since) holds the target; no other heliostat is moved until it is parked
  (parking and stowing, which take beam-safe paths to standby, are always allowed);
* the database's campaign lock (:class:`controller.storage.lock.CampaignLock`) is held while
  the console drives anything, so a CLI campaign and the console never drive together.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from controller.alarms.conditions import DRIVE_LINK_DOWN
from controller.calibration.campaign.field import Field
from controller.calibration.cycle.commissioning import Commissioning
from controller.commands._id_lists import id_list
from controller.console.events import EventBus
from controller.devices.drive import Drive, DriveError, DriveLimits, DriveStatus
from controller.devices.lamp_panel import fiducial_hook
from controller.errors import HeliocalError, InputError
from controller.storage.alarms import AlarmBook

STATUS_POLL_S = 0.1  # wall seconds between two status readings of every drive


class Conflict(HeliocalError):
    """The request cannot run now (campaign running, target held, database in use): HTTP 409."""

    exit_code = 2
    outcome = "not_executed"


@dataclass
class PlantHooks:
    """What a plant other than the field hands the console besides its field: ``safety``, a
    callable returning the plant's own beam-safety count (``{"samples", "violations",
    "max_beams_on_target"}``); ``set_night(k)``: the plant is on night ``k`` now (a simulated
    plant's drift); ``label`` shown in the page header. Defaults: no truth."""

    safety: Callable[[], dict] | None = None
    set_night: Callable[[int], None] | None = None
    label: str = "field"


@dataclass
class LinkHealth:
    """Status polling of one drive: readings, failures in a row, last error, last good reading."""

    polls: int = 0
    failures: int = 0
    last_error: str | None = None
    last_ok: float | None = None  # time.monotonic()

    def to_json(self) -> dict:
        age = None if self.last_ok is None else round(time.monotonic() - self.last_ok, 3)
        return {"ok": self.failures == 0 and self.last_ok is not None, "polls": self.polls,
                "failures_in_a_row": self.failures, "last_error": self.last_error, "age_s": age}


def status_json(st: DriveStatus) -> dict:
    """A drive status with targets and limit switches (more than the CLI's ``to_json``)."""
    return {**st.to_json(), "az_target": st.az_target, "el_target": st.el_target,
            "limit_az": st.limit_az, "limit_el": st.limit_el}


def only_keys(body: dict, allowed: tuple[str, ...], what: str) -> None:
    """A request body names only the fields its request takes (argparse refuses an unknown
    option likewise); InputError naming the first other one."""
    other = [k for k in body if k not in allowed]
    if other:
        takes = ", ".join(allowed) if allowed else "no field"
        raise InputError(f"{what}: unknown field {other[0]!r} (takes {takes})")


class Console:
    """The console's plant: the :class:`controller.calibration.campaign.field.Field` its campaigns, nights
    and commissioning sessions run on (``field.cfg``: for a simulated plant, its rewritten copy;
    ``field.store``: the writer :class:`controller.storage.db.CampaignStore`); the calibration
    target's camera is the one commissioning looks through."""

    def __init__(self, plant: Field, *, heliostat_ids: list[str] | None = None,
                 library_path: str | None = None,
                 hooks: PlantHooks | None = None, work_dir: str | Path, reports_dir: str | None = None,
                 poll_s: float = STATUS_POLL_S, move_timeout_s: float = 300.0) -> None:
        cfg = plant.cfg
        self.field = plant
        self.cfg = cfg
        self.config_path = plant.config_path
        self.store = plant.store
        self.camera = plant.camera()
        self.ids = list(heliostat_ids) if heliostat_ids else [h.id for h in cfg.heliostats]
        for hid in self.ids:
            cfg.heliostat(hid)
        self.library = plant.library
        self.library_path = library_path
        self.hooks = hooks or PlantHooks()
        self.work_dir = Path(work_dir)
        self.reports_dir = reports_dir
        self.poll_s = poll_s
        self.move_timeout_s = move_timeout_s
        self.bus = EventBus()
        self.status: dict[str, dict | None] = dict.fromkeys(self.ids)
        self.health = {hid: LinkHealth() for hid in self.ids}
        self.sessions: dict[str, Commissioning] = {}
        self.logs: dict[str, list[dict]] = {hid: [] for hid in self.ids}
        self._busy = {hid: threading.Lock() for hid in self.ids}
        self._claim = threading.Lock()  # target claim + campaign lock decisions
        self._stop = threading.Event()
        self._poller: threading.Thread | None = None
        self.alarms = AlarmBook(self.store)
        self.campaign = None  # controller.console.campaigns.CampaignControl, set by the app
        self.night = None  # controller.console.nights.NightControl, set by the app

    # -- devices --------------------------------------------------------------------------------
    def known(self, hid: str) -> str:
        if hid not in self.status:
            shown = ", ".join(self.ids[:20]) + (f", … ({len(self.ids)} in all)" if len(self.ids) > 20 else "")
            raise InputError(f"unknown heliostat {hid!r} (this console has {shown})")
        return hid

    def drive(self, hid: str) -> Drive:
        return self.field.drive(hid)

    def session(self, hid: str) -> Commissioning:
        """The commissioning session of ``hid`` (opened on first use; reads the drive), aiming
        with the heliostat's latest fitted model."""
        model = self.store.latest_model(hid)
        if hid not in self.sessions:
            self.sessions[hid] = Commissioning(self.cfg, hid, self.drive(hid), self.camera,
                                               library=self.library, model=model,
                                               move_timeout_s=self.move_timeout_s,
                                               fiducial_lamps=fiducial_hook(self.cfg))
        self.sessions[hid].model = model
        return self.sessions[hid]

    # -- live status ----------------------------------------------------------------------------
    def start(self) -> None:
        self._poller = threading.Thread(target=self._poll_loop, name="console-status", daemon=True)
        self._poller.start()

    def close(self) -> dict[str, dict]:
        """Stop polling, stop a running campaign (its beams parked), park what the console
        moved; returns what was done per heliostat (:meth:`make_safe`)."""
        self._stop.set()
        if self._poller is not None:
            self._poller.join(timeout=5.0)
        for control in (self.campaign, self.night):
            if control is not None:
                control.shutdown()
        done = self.make_safe()
        self.bus.close()
        return done

    @property
    def closing(self) -> threading.Event:
        """Set when the console shuts down (background threads end)."""
        return self._stop

    def commands_running(self) -> bool:
        return any(lock.locked() for lock in self._busy.values())

    def _poll_loop(self) -> None:
        while not self._stop.is_set():
            t0 = time.monotonic()
            for hid in self.ids:
                if self._stop.is_set():
                    return
                self.poll(hid)
            self._stop.wait(max(0.0, self.poll_s - (time.monotonic() - t0)))

    def poll(self, hid: str) -> dict | None:
        """Read ``hid``'s drive once; publish a ``drive`` event when anything changed."""
        h = self.health[hid]
        h.polls += 1
        try:
            st = status_json(self.drive(hid).status())
        except HeliocalError as exc:
            changed = h.failures == 0
            h.failures += 1
            h.last_error = str(exc)
            if h.failures == self.cfg.alarms.link_failures:
                self.alarms.raise_alarm(DRIVE_LINK_DOWN, hid,
                                        f"{hid}: {h.failures} status readings failed in a row: {exc}")
            if changed:
                self.bus.publish("drive", {"heliostat": hid, "status": self.status[hid], "link": h.to_json()})
            return None
        was_failing = h.failures > 0
        if h.failures >= self.cfg.alarms.link_failures:
            self.alarms.clear_alarm(DRIVE_LINK_DOWN, hid)
        h.failures, h.last_ok = 0, time.monotonic()
        if st != self.status[hid] or was_failing:
            self.status[hid] = st
            self.bus.publish("drive", {"heliostat": hid, "status": st, "link": h.to_json()})
        return st

    # -- commands -------------------------------------------------------------------------------
    def holder(self) -> str | None:
        """The heliostat whose beam may be on the target after a manual command, if any."""
        return next((h for h, s in self.sessions.items() if s.needs_parking), None)

    @contextmanager
    def command(self, hid: str, *, moves: bool, beam_safe: bool = False):
        """Run one manual command on ``hid`` under the safety rules of the module docstring.
        ``moves``: the command moves the heliostat (takes the campaign lock); ``beam_safe``:
        its path keeps the beam off the target (park, stow), allowed while another holds it."""
        self.known(hid)
        if self.driving() is not None:
            raise Conflict(f"{self.driving()} is running: its state machines drive the heliostats and use "
                           "the camera; pause, abort or stop it first")
        if not self._busy[hid].acquire(blocking=False):
            raise Conflict(f"{hid}: the previous command is still running")
        try:
            with self._claim:
                other = self.holder()
                if moves and not beam_safe and other not in (None, hid):
                    raise Conflict(f"{other} may have its beam on the target: park it first (one beam per "
                                   "target)")
                if moves:
                    self.store.campaign_lock.acquire("console")  # DatabaseBusy names the owner
            yield self.session(hid)
        finally:
            self._busy[hid].release()
            self.release_lock_if_idle()
            self.poll(hid)

    def heliostats_for(self, what: str, ids: list[str] | None) -> list[str]:
        """The heliostats a campaign or night started from the page runs on: the ticked ones
        (at least one), else all of the console's."""
        if ids is None:
            return list(self.ids)
        if ids == []:
            raise InputError(f"{what}: tick at least one heliostat")
        return id_list(ids, "heliostats", self.known)  # as the CLI checks --heliostats

    def take_over(self) -> None:
        """Before a campaign or a night drives the heliostats: nothing else drives them, no beam
        is left on the target by a manual command, no manual command runs (Conflict, 409), then
        the database's campaign lock (DatabaseBusy names the CLI's campaign). Commissioning
        sessions start afresh (the runs change their standby side)."""
        if self.driving() is not None:
            raise Conflict(f"{self.driving()} is running")
        if self.holder() is not None:
            raise Conflict(f"{self.holder()} may have its beam on the target after a manual command: "
                           "park it first (one beam per target)")
        if self.commands_running():
            raise Conflict("a manual command is still running")
        self.store.campaign_lock.acquire("console")
        self.sessions.clear()

    def driving(self) -> str | None:
        """What drives the heliostats now ("campaign NAME", "night NAME"), or None."""
        if self.campaign is not None and self.campaign.running:
            return f"campaign {self.campaign.name}"
        if self.night is not None and self.night.running:
            return f"night {self.night.snapshot()['name']}"
        return None

    def release_lock_if_idle(self) -> None:
        """Give the database's campaign lock back once nothing the console moved needs parking
        and no campaign runs, so a CLI campaign can start."""
        with self._claim:
            if self.driving() is None and self.holder() is None and self.store.campaign_lock.held:
                self.store.campaign_lock.release()

    def log(self, hid: str, step: str, result: dict) -> dict:
        entry = {"step": step, "utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "result": result}
        self.logs[hid].append(entry)
        self.bus.publish("commission", {"heliostat": hid, **entry})
        return result

    def make_safe(self) -> dict[str, dict]:
        """Console shutdown: park every heliostat a session left possibly on the target."""
        out = {}
        for hid, s in list(self.sessions.items()):
            if s.needs_parking:
                out[hid] = s.make_safe()
        self.release_lock_if_idle()
        return out


def read_limits(console: Console, hid: str) -> dict:
    """Soft limits of the configuration and of the firmware, and whether they agree."""
    h = console.cfg.heliostat(hid)
    cfg_lim = DriveLimits.from_axes(h.axes)
    try:
        fw = console.drive(hid).get_limits()
    except DriveError as exc:
        return {"config": _lim(cfg_lim), "firmware": None, "agree": False, "error": str(exc)}
    return {"config": _lim(cfg_lim), "firmware": _lim(fw), "agree": _lim(fw) == _lim(cfg_lim)}


def _lim(lim: DriveLimits) -> dict:
    return {"az": [lim.az.min_steps, lim.az.max_steps], "el": [lim.el.min_steps, lim.el.max_steps]}
