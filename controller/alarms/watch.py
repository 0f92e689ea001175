"""What a campaign and a night tell the plant's alarm list and audit trail.

:class:`FieldWatch` is one more observer of every campaign (the runner adds it): from each
heliostat's recorded run it raises or clears the alarms of its drive's link, its camera, a
refused beam-unsafe path, three no-beams in a row on the target and a drift beyond the limit,
and records each model the run changed. :func:`night_alarms` does the same for the end of a
night: a partial night, and each heliostat's predicted daytime error against the limit.

A run's fault cause starts with the name of the error that caused it
(:meth:`controller.calibration.cycle.machine.CalibrationCycle.run`: ``"LinkError: …"``); the fault
classes below are read from there.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable, Mapping

from controller.alarm_config import AlarmLimits
from controller.alarms.conditions import (
    BEAM_SAFETY_REFUSAL,
    CAMERA_GONE,
    DAYTIME_ERROR_HIGH,
    DRIFT_HIGH,
    DRIVE_LINK_DOWN,
    NIGHT_PARTIAL,
    NO_BEAM_REPEATED,
)
from controller.alarms.sink import AlarmSink, AuditSink
from controller.calibration.campaign.observers import CampaignObserver
from controller.calibration.records import RunRecord

LINK_FAULTS = ("LinkError",)  # controller.devices.drive.LinkError
CAMERA_FAULTS = ("CameraError", "IncompleteFrame")  # controller.devices.camera, gige_device
SAFETY_FAULTS = ("UnsafePath",)  # controller.calibration.cycle.beam_safety.UnsafePath
NO_BEAMS_IN_A_ROW = 3


def fault_kind(run: RunRecord) -> str:
    """The error class that ended ``run`` (the first word of its fault cause), or ''."""
    cause = run.fault_cause or ""
    head = cause.split(":", 1)[0].strip()
    return head if head.isidentifier() else ""


class FieldWatch(CampaignObserver):
    """Alarms and model audit of one campaign on ``target`` (module docstring). ``with_models``:
    which of some heliostats have a fitted model (who had one before: drift is measured against it)."""

    def __init__(self, alarms: AlarmSink, audit: AuditSink, limits: AlarmLimits, target: str, campaign: str,
                 with_models: Callable[[list[str]], set[str]]) -> None:
        self.alarms, self.audit, self.limits = alarms, audit, limits
        self.target, self.campaign = target, campaign
        self.with_models = with_models
        self.had_model: set[str] = set()
        self._no_beams = 0
        self._lock = threading.Lock()

    def campaign_started(self, campaign_id: int, queue: list[str], done: set[str]) -> None:
        self.had_model = self.with_models(list(queue))

    def run_recorded(self, campaign_id: int, run: RunRecord) -> None:
        hid, kind, seen = run.heliostat_id, fault_kind(run), bool(run.measurements)
        a = self.alarms
        if kind in LINK_FAULTS:
            a.raise_alarm(DRIVE_LINK_DOWN, hid, f"{hid}: {run.fault_cause}")
        elif seen or run.status != "failed":
            a.clear_alarm(DRIVE_LINK_DOWN, hid)
        if kind in SAFETY_FAULTS:
            a.raise_alarm(BEAM_SAFETY_REFUSAL, hid, f"{hid}: {run.fault_cause}")
        elif seen:
            a.clear_alarm(BEAM_SAFETY_REFUSAL, hid)
        if kind in CAMERA_FAULTS:
            a.raise_alarm(CAMERA_GONE, self.target, f"camera of {self.target}: {run.fault_cause}")
        elif seen:
            a.clear_alarm(CAMERA_GONE, self.target)
        self._count_no_beam(run)
        e = run.error_before_mrad
        if e is not None and hid in self.had_model:
            if e > self.limits.drift_limit_mrad:
                a.raise_alarm(DRIFT_HIGH, hid, f"{hid}: pointing error {e:.2f} mrad with its model "
                              f"(limit {self.limits.drift_limit_mrad:g} mrad)")
            else:
                a.clear_alarm(DRIFT_HIGH, hid)
        if run.model is not None:
            self.audit.record("model.update", hid, f"{self.campaign}: fitted on {run.model.n_measurements} "
                              "measurements")

    def _count_no_beam(self, run: RunRecord) -> None:
        with self._lock:
            if run.status == "no_beam":
                self._no_beams += 1
                row = self._no_beams
            elif run.measurements:
                self._no_beams = row = 0
            else:
                return
        if row >= NO_BEAMS_IN_A_ROW:
            self.alarms.raise_alarm(NO_BEAM_REPEATED, self.target,
                                    f"{row} heliostats in a row without a beam on {self.target} "
                                    f"({self.campaign}); last {run.heliostat_id}")
        elif row == 0:
            self.alarms.clear_alarm(NO_BEAM_REPEATED, self.target)


def night_ended(plant, name: str, status: str, cause: str | None, predicted: Mapping[str, float],
                heliostats: Iterable[str]) -> None:
    """The end of night ``name`` on ``plant`` (a :class:`controller.calibration.campaign.field.Field`):
    audited, and its alarms (:func:`night_alarms`)."""
    plant.audit.record("night.end", name, status + (f": {cause}" if cause else ""))
    night_alarms(plant.alarms, plant.cfg.alarms, name, status, cause, predicted, heliostats)


def night_alarms(alarms: AlarmSink, limits: AlarmLimits, name: str, status: str, cause: str | None,
                 predicted: Mapping[str, float], heliostats: Iterable[str]) -> None:
    """At the end of night ``name``: a partial night raises :data:`NIGHT_PARTIAL` (a finished one
    clears it), and each of ``heliostats`` whose predicted daytime RMS (mrad) is beyond the limit
    raises :data:`DAYTIME_ERROR_HIGH` (within it: cleared)."""
    if status == "partial":
        alarms.raise_alarm(NIGHT_PARTIAL, "night", f"{name} ended partial: {cause}")
    elif status == "finished":
        alarms.clear_alarm(NIGHT_PARTIAL, "night")
    limit = limits.daytime_error_limit_mrad
    for hid in heliostats:
        rms = predicted.get(hid)
        if rms is None or rms != rms:  # no model: nothing predicted
            continue
        if rms > limit:
            alarms.raise_alarm(DAYTIME_ERROR_HIGH, hid, f"{hid}: predicted daytime error {rms:.2f} mrad RMS "
                               f"after {name} (limit {limit:g} mrad)")
        else:
            alarms.clear_alarm(DAYTIME_ERROR_HIGH, hid)
