"""A campaign started from the console: the CLI's runner
(:class:`controller.calibration.campaign.runner.Campaign`) in a background thread, followed
through its observer hooks and published as ``campaign`` events.

What the page shows: the queue with each heliostat's state, who is on the target, progress and
ETA (wall time per recorded heliostat so far times those left), the beam-safety state (the
number of cycles in on-target states, at most one by the target gate; the plant's own count
when the plant gives one) and the outcome. Start takes the database's campaign lock like
``heliocal campaign run``; pause holds the queue (cycles in flight finish); abort parks every
beam and records the session ``interrupted`` (start it again to resume).
"""

from __future__ import annotations

import threading
import time

from controller.calibration.campaign.runner import Campaign, CampaignObserver, CampaignOptions
from controller.calibration.night.planned import calibration_night
from controller.console.backend import Conflict, Console
from controller.errors import HeliocalError, InputError
from controller.storage.nights import NightBook

# States in which a cycle's beam is (or is moving) on the target (controller.calibration.cycle.machine).
ON_TARGET = ("slewing", "settling", "capturing", "merging", "analysing", "matching", "verifying",
             "correcting")


class CampaignControl(CampaignObserver):
    """Start / pause / resume / abort one campaign at a time; :meth:`snapshot` for the page."""

    def __init__(self, console: Console) -> None:
        self.c = console
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._campaign: Campaign | None = None
        self.name: str | None = None
        self.campaign_id: int | None = None
        self.queue: list[str] = []
        self.states: dict[str, str] = {}
        self.recorded: dict[str, dict] = {}
        self.paused = False
        self.outcome: dict | None = None
        self.started: float | None = None
        self.max_on_target = 0

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # -- control ----------------------------------------------------------------------------------
    def start(self, name: str, ids: list[str] | None = None) -> dict:
        c = self.c
        ids = c.heliostats_for("campaign", ids)
        if not name or not name.strip():
            raise InputError("campaign name: give a name")
        with self._lock:
            c.take_over()
            camp = Campaign(c.field, CampaignOptions(name=name.strip()), heliostat_ids=ids, observers=[self])
            self._campaign, self.name, self.campaign_id = camp, name.strip(), None
            self.queue, self.states, self.recorded = list(ids), {}, {}
            self.paused, self.outcome, self.started, self.max_on_target = False, None, time.monotonic(), 0
            self._thread = threading.Thread(target=self._run, args=(camp,), name="console-campaign",
                                            daemon=True)
            self._thread.start()
        self._publish("started")
        return self.snapshot()

    def _run(self, camp: Campaign) -> None:
        try:
            r = calibration_night(NightBook(self.c.store), camp)
            self.outcome = {"status": r.status, "cause": r.cause, "campaign_id": r.campaign_id}
        except HeliocalError as exc:
            self.outcome = {"status": "error", "cause": str(exc), "campaign_id": self.campaign_id}
        except Exception as exc:  # the runner recorded it as aborted; the page must say why
            self.outcome = {"status": "aborted", "cause": f"{type(exc).__name__}: {exc}",
                            "campaign_id": self.campaign_id}
        finally:
            self._thread = None
            self.c.release_lock_if_idle()
            self._publish("finished")

    def pause(self) -> dict:
        camp = self._require()
        camp.pause()
        self.paused = True
        self._publish("paused")
        return self.snapshot()

    def resume(self) -> dict:
        camp = self._require()
        camp.resume()
        self.paused = False
        self._publish("resumed")
        return self.snapshot()

    def abort(self) -> dict:
        camp = self._require()
        camp.request_stop()
        self.paused = False
        self._publish("aborting")
        return self.snapshot()

    def _require(self) -> Campaign:
        if not self.running or self._campaign is None:
            raise Conflict("no campaign is running")
        return self._campaign

    def shutdown(self, timeout_s: float = 60.0) -> None:
        """Console shutdown: stop a running campaign (beams parked) and wait for it."""
        t = self._thread
        if t is not None and self._campaign is not None:
            self._campaign.request_stop()
            t.join(timeout_s)

    # -- observer hooks (cycle threads) ---------------------------------------------------------------
    def campaign_started(self, campaign_id: int, queue: list[str], done: set[str]) -> None:
        self.campaign_id, self.queue = campaign_id, list(queue)
        for hid in done:
            self.states[hid] = "recorded earlier"
        self._publish("queue")

    def state_changed(self, heliostat_id: str, state: str) -> None:
        self.states[heliostat_id] = state
        self.max_on_target = max(self.max_on_target, len(self.on_target()))
        self._publish("state", heliostat=heliostat_id, state=state)

    def run_recorded(self, campaign_id: int, run) -> None:
        self.recorded[run.heliostat_id] = {"status": run.status, "iterations": run.iterations,
                                           "error_before_mrad": run.error_before_mrad,
                                           "error_after_mrad": run.error_after_mrad,
                                           "fault_cause": run.fault_cause}
        self._publish("recorded", heliostat=run.heliostat_id)

    def campaign_finished(self, campaign_id: int, status: str) -> None:
        self._publish("status", status=status)

    # -- what the page shows ------------------------------------------------------------------------
    def on_target(self) -> list[str]:
        return [h for h, s in list(self.states.items()) if s in ON_TARGET]

    def snapshot(self) -> dict:
        done = len(self.recorded) + sum(1 for s in self.states.values() if s == "recorded earlier")
        total = len(self.queue)
        elapsed = time.monotonic() - self.started if self.started is not None else None
        session = len(self.recorded)
        eta = (elapsed / session * (total - done)) if (self.running and session and elapsed) else None
        on = self.on_target()
        safety = {"on_target": on, "max_on_target": self.max_on_target,
                  "state": "ok" if self.max_on_target <= 1 else "VIOLATION: two beams on the target"}
        if self.c.hooks.safety is not None:
            safety["plant"] = self.c.hooks.safety()
        if self.outcome and "beam may have been left" in (self.outcome.get("cause") or ""):
            safety["state"] = "target blocked: a beam may have been left on it"
        return {"running": self.running, "paused": self.paused, "name": self.name,
                "campaign_id": self.campaign_id, "queue": [
                    {"heliostat": h, "state": self.states.get(h, "queued"), **self.recorded.get(h, {})}
                    for h in self.queue],
                "progress": {"done": done, "total": total, "elapsed_s": elapsed, "eta_s": eta},
                "target": {"holder": on[0] if on else None}, "beam_safety": safety,
                "outcome": self.outcome}

    def _publish(self, what: str, **extra) -> None:
        self.c.bus.publish("campaign", {"what": what, **extra, "snapshot": self.snapshot()})
