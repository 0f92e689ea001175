"""Recovery when the camera sees no beam (docs/campaigns.md, "No beam").

A cycle whose frame holds no beam by the presence decision (:class:`NoBeam`) computes no
correction from it: it records ``no_beam``, parks the heliostat off the target (the fault
path) and names the heliostat and the statistic in its cause. One heliostat without a beam is
its own problem (its beam missed the target). ``STOP_AFTER`` heliostats in a row without a beam
point at what they share — the light source, the camera — so :class:`NoBeamWatch` stops the
pass: every heliostat not started yet is recorded ``no_beam`` without being moved, and the
cause says what the lamp's confirmation said: confirmed lit by the lamp panel (then the lamp
gives no light though its input says lit, or the camera looks elsewhere) or only asked of the
operator (then check that it is lit).
"""

from __future__ import annotations

import threading

from controller.calibration.field import LampLit
from controller.calibration.records import RunRecord

NO_BEAM = "no_beam"  # RunRecord.status of a heliostat whose frames held no beam
STOP_AFTER = 3  # consecutive no-beam heliostats that stop the pass


class NoBeamWatch:
    """Counts consecutive ``no_beam`` runs of a pass (thread-safe; runs end in any order)."""

    def __init__(self, light_source: str, target: str, lit: LampLit | None = None,
                 stop_after: int = STOP_AFTER) -> None:
        self.light_source = light_source
        self.target = target
        self.lit = lit
        self.stop_after = stop_after
        self._row = 0
        self._lock = threading.Lock()

    def ended(self, run: RunRecord) -> None:
        """A heliostat's run ended: a beam seen (any measurement) resets the count."""
        with self._lock:
            if run.status == NO_BEAM:
                self._row += 1
            elif run.measurements:
                self._row = 0

    @property
    def stopped(self) -> bool:
        with self._lock:
            return self._row >= self.stop_after

    def not_measured(self, heliostat_id: str, queue_index: int, now_s: float) -> RunRecord:
        """The record of a heliostat the stopped pass does not move."""
        cause = (f"{heliostat_id}: not moved: no beam on target {self.target} for {self._row} heliostats "
                 f"in a row; {self._lamp_hint()}")
        return RunRecord(heliostat_id, queue_index, NO_BEAM, "idle", 0, start_s=now_s, end_s=now_s,
                         fault_cause=cause)

    def _lamp_hint(self) -> str:
        src, lit = self.light_source, self.lit
        if lit is not None and lit.confirmed:
            return (f"light source {src} was confirmed lit by the lamp {lit.by} at {lit.utc}: check that it "
                    f"gives light (a confirmation input can say lit while the lamp is dark) and that the "
                    f"camera sees target {self.target}")
        return (f"check that light source {src} is lit and confirmed (it was not confirmed by a lamp "
                f"panel) and that the camera sees target {self.target}")
