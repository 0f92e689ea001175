"""Live campaign progress in the terminal (rich): a campaign observer."""

from __future__ import annotations

import threading

from controller.calibration.campaign.runner import CampaignObserver
from controller.calibration.records import RunRecord

_QUIET_STATES = ("preparing",)
_FINAL_STATES = ("done", "stowed", "aborted")


class TerminalProgress(CampaignObserver):
    """A rich progress bar with ETA and the heliostats' current states, on stderr."""

    def __init__(self) -> None:
        self._states: dict[str, str] = {}
        self._lock = threading.Lock()
        self._p = None

    def campaign_started(self, campaign_id: int, queue: list[str], done: set[str]) -> None:
        if len(done) >= len(queue):
            return
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        self._p = Progress(TextColumn("[bold]campaign"), BarColumn(), MofNCompleteColumn(), TextColumn("ETA"),
                           TimeRemainingColumn(), TextColumn("{task.description}"), transient=False)
        self._p.start()
        self._task = self._p.add_task("", total=len(queue), completed=len(done))

    def state_changed(self, heliostat_id: str, state: str) -> None:
        if self._p is None:
            return
        with self._lock:
            if state in _FINAL_STATES:
                self._states.pop(heliostat_id, None)
            else:
                self._states[heliostat_id] = state
            desc = " ".join(f"{h}:{s}" for h, s in sorted(self._states.items()) if s not in _QUIET_STATES)
            self._p.update(self._task, description=desc[:90])

    def run_recorded(self, campaign_id: int, run: RunRecord) -> None:
        if self._p is not None:
            self._p.advance(self._task)

    def campaign_finished(self, campaign_id: int, status: str) -> None:
        if self._p is not None:
            self._p.stop()
            self._p = None
