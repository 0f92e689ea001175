"""The alarm conditions heliocal watches, each with its priority (docs/plant-integration.md).

One alarm exists per condition and object (a lamp, a heliostat, a target, the night), never one
per occurrence: the object is the alarm's ``source``. Priorities follow ISA-18.2's three levels;
``severity`` is the OPC UA event severity (1–1000) each maps to.
"""

from __future__ import annotations

from dataclasses import dataclass

PRIORITIES = ("high", "medium", "low")
SEVERITY = {"high": 800, "medium": 500, "low": 200}  # OPC UA Severity 1..1000

LAMP_NOT_DARK = "lamp_not_dark"
LAMP_NOT_LIT = "lamp_not_lit"
DRIVE_LINK_DOWN = "drive_link_down"
CAMERA_GONE = "camera_gone"
NO_BEAM_REPEATED = "no_beam_repeated"
BEAM_SAFETY_REFUSAL = "beam_safety_refusal"
DAYTIME_ERROR_HIGH = "daytime_error_high"
DRIFT_HIGH = "drift_high"
NIGHT_PARTIAL = "night_partial"


@dataclass(frozen=True)
class Condition:
    """An alarm condition: its id, priority, what its source is and what it means."""

    id: str
    priority: str
    source: str  # what kind of object the alarm's source names
    meaning: str

    @property
    def severity(self) -> int:
        return SEVERITY[self.priority]


CONDITIONS: dict[str, Condition] = {c.id: c for c in (
    Condition(LAMP_NOT_DARK, "high", "lamp channel",
              "a lamp switched off did not confirm dark: a beam may still be reflected in the field"),
    Condition(LAMP_NOT_LIT, "medium", "lamp channel", "a lamp switched on did not confirm lit"),
    Condition(DRIVE_LINK_DOWN, "high", "heliostat", "the heliostat's drive does not answer on its link"),
    Condition(CAMERA_GONE, "high", "target", "the camera looking at the target failed or is gone"),
    Condition(NO_BEAM_REPEATED, "medium", "target",
              "three heliostats in a row without a beam on the target: the lamp or the camera"),
    Condition(BEAM_SAFETY_REFUSAL, "high", "heliostat",
              "a move was refused because its path would put a beam where it must not be"),
    Condition(DAYTIME_ERROR_HIGH, "low", "heliostat",
              "the heliostat's predicted daytime error is beyond alarms.daytime_error_limit_mrad"),
    Condition(DRIFT_HIGH, "low", "heliostat",
              "the heliostat's measured pointing error with its model is beyond alarms.drift_limit_mrad"),
    Condition(NIGHT_PARTIAL, "low", "night",
              "a night ended partial: some planned geometries were not measured"),
)}


def condition(cid: str) -> Condition:
    """The condition ``cid``; ValueError naming the known ones otherwise (a programming error)."""
    if cid not in CONDITIONS:
        raise ValueError(f"unknown alarm condition {cid!r} (known: {', '.join(CONDITIONS)})")
    return CONDITIONS[cid]
