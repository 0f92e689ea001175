"""What one planned night did: :class:`NightSummary` (the ``campaign night --json`` keys, the
night record's summary), returned by :class:`controller.calibration.night.planned.PlannedNight`."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class NightSummary:
    """What one planned night did (the ``campaign night --json`` keys): ``planned`` and
    ``measured`` geometries, ``failed`` planned geometries not measured, the ``lamps`` lit
    (each with its confirmation), the field's daytime error its models now predict (open
    loop, from their covariance), ``status`` (finished / partial / aborted / interrupted);
    ``unmeasurable``: the heliostats with no measurable geometry tonight, each with why
    (:class:`controller.calibration.night.planner.Unmeasurable`)."""

    night: int
    name: str
    heliostats: int
    planned: int
    measured: int
    failed: int
    lamps: list[dict]
    daytime_error_predicted_mrad: dict
    status: str
    cause: str | None = None
    first_calibrated: list[str] = field(default_factory=list)  # measured at the calibration lamp first
    passes: list[dict] = field(default_factory=list)
    lamp_changes: list[dict] = field(default_factory=list)
    unmeasurable: list[dict] = field(default_factory=list)
    lights_out: list[dict] = field(default_factory=list)  # every lamp as the night left it (LampEnd)
    flagged: list[dict] = field(default_factory=list)  # geometries that failed on two nights, not planned

    @property
    def exit_code(self) -> int:
        return {"finished": 0, "partial": 3, "interrupted": 130}.get(self.status, 1)

    def to_json(self) -> dict:
        return {"night": self.night, "name": self.name, "heliostats": self.heliostats,
                "planned": self.planned,
                "measured": self.measured, "failed": self.failed, "lamps": self.lamps,
                "daytime_error_predicted_mrad": self.daytime_error_predicted_mrad, "status": self.status,
                "cause": self.cause, "first_calibrated": self.first_calibrated, "passes": self.passes,
                "lamp_changes": self.lamp_changes, "unmeasurable": self.unmeasurable,
                "lights_out": self.lights_out, "flagged": self.flagged}


def night_status(results: list, stopped: bool, daylight: str | None = None) -> tuple[str, str | None]:
    """The night's status from its campaigns' (:class:`CampaignResult` s): the first that did not
    run to its end decides; else ``partial`` when ``daylight`` (why the night's time ended:
    :func:`controller.calibration.beams.policy.night_over`) left passes not started, or a pass
    ended partial; else ``finished``."""
    for r in results:
        if r.status == "interrupted" or (stopped and r.status not in ("finished", "partial")):
            return "interrupted", "stopped by the operator; rerun to resume"
        if r.status == "aborted":
            return "aborted", f"{r.name}: {r.cause}"
    if stopped:
        return "interrupted", "stopped by the operator; rerun to resume"
    causes = [f"{r.name}: {r.cause}" for r in results if r.status == "partial"][:3]
    if daylight:
        causes.insert(0, f"{daylight}: the passes not started are planned again by the next night")
    return ("partial", "; ".join(causes)) if causes else ("finished", None)
