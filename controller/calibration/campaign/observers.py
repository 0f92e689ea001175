"""What a campaign tells the outside world (:class:`CampaignObserver`): a terminal progress
bar, the web console, a simulated plant's truth recorder. Hooks run on the campaign's threads
and must return quickly."""

from __future__ import annotations

from collections.abc import Sequence

from controller.calibration.campaign.field import LampEnd
from controller.calibration.cycle.context import CycleObserver
from controller.calibration.records import MeasurementRecord, RunRecord


class CampaignObserver(CycleObserver):
    """What a campaign tells the outside world, besides every cycle's :class:`CycleObserver`
    hooks; every hook defaults to doing nothing."""

    def campaign_started(self, campaign_id: int, queue: list[str], done: set[str]) -> None:
        """The campaign (re)started; ``done`` are the heliostats recorded in earlier sessions."""

    def run_recorded(self, campaign_id: int, run: RunRecord) -> None:
        """A heliostat's run was committed (``run.id`` is its database id)."""

    def campaign_finished(self, campaign_id: int, status: str) -> None:
        """The session ended with ``status`` (one of ``records.CAMPAIGN_STATUSES``)."""

    def light_source_needed(self, source_id: str) -> None:
        """The campaign is about to move heliostats for light source ``source_id``: it must be
        lit now (an operator or a lamp controller does so; a simulated plant switches it)."""

    def fiducial_lamps(self, on: bool) -> None:
        """The target's fiducial lamps must be on (``on``) or off now, for the camera
        registration's fiducial frame (docs/camera.md, "Registration")."""

    def lamp_not_dark(self, session: str, lamp: LampEnd) -> None:
        """At the end of night or campaign ``session`` a lamp was not confirmed dark
        (``lamp.state`` ``lit`` or ``no_answer``; docs/lamps.md, "Lights out"): already recorded
        in the ``lamp_states`` table; an alarm list raises it from here."""


class Observers(CampaignObserver):
    """Fans every hook out to several observers, in order."""

    def __init__(self, observers: Sequence[CampaignObserver]) -> None:
        self._all = list(observers)

    def state_changed(self, heliostat_id: str, state: str) -> None:
        for o in self._all:
            o.state_changed(heliostat_id, state)

    def measured(self, heliostat_id: str, measurement: MeasurementRecord) -> None:
        for o in self._all:
            o.measured(heliostat_id, measurement)

    def campaign_started(self, campaign_id: int, queue: list[str], done: set[str]) -> None:
        for o in self._all:
            o.campaign_started(campaign_id, queue, done)

    def run_recorded(self, campaign_id: int, run: RunRecord) -> None:
        for o in self._all:
            o.run_recorded(campaign_id, run)

    def campaign_finished(self, campaign_id: int, status: str) -> None:
        for o in self._all:
            o.campaign_finished(campaign_id, status)

    def light_source_needed(self, source_id: str) -> None:
        for o in self._all:
            o.light_source_needed(source_id)

    def fiducial_lamps(self, on: bool) -> None:
        for o in self._all:
            o.fiducial_lamps(on)

    def lamp_not_dark(self, session: str, lamp: LampEnd) -> None:
        for o in self._all:
            o.lamp_not_dark(session, lamp)
