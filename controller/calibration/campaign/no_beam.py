"""Recovery when the camera sees no beam (docs/campaigns.md, "No beam").

A cycle whose frame holds no beam by the presence decision (:class:`NoBeam`) computes no
correction from it: it records ``no_beam``, parks the heliostat off the target (the fault
path) and names the heliostat and the statistic in its cause. One heliostat without a beam is
its own problem (its beam missed the target). ``STOP_AFTER`` heliostats in a row without a beam
point at what they share — the light source, the camera — so :class:`NoBeamWatch` stops the
pass: every heliostat not started yet is recorded ``no_beam`` without being moved, those
already on their way to standby or waiting there are held back (parked at standby, their beam
never put on the target), and the cause says what the lamp's confirmation said: confirmed lit
by the lamp panel (then the lamp gives no light though its input says lit, or the camera looks
elsewhere) or only asked of the operator (then check that it is lit).
"""

from __future__ import annotations

import threading
from collections.abc import Iterable, Mapping
from typing import Any

from controller.calibration.campaign.field import LampLit
from controller.calibration.cycle.context import CycleObserver
from controller.calibration.records import MeasurementRecord, RunRecord

NO_BEAM = "no_beam"  # RunRecord.status of a heliostat whose frames held no beam
STOP_AFTER = 3  # consecutive no-beam heliostats that stop the pass
WAITING = ("idle", "preparing", "standby")  # cycle states before its beam goes onto the target


class NoBeamWatch:
    """Counts consecutive heliostats without a beam in a pass (thread-safe; runs end in any
    order). Each heliostat counts once: when its frame is refused (:meth:`refused`, told by
    :class:`RefusalObserver` before the cycle parks and hands the target on) or when its run
    ends (:meth:`ended`), whichever comes first."""

    def __init__(self, light_source: str, target: str, lit: LampLit | None = None,
                 stop_after: int = STOP_AFTER) -> None:
        self.light_source = light_source
        self.target = target
        self.lit = lit
        self.stop_after = stop_after
        self._row = 0
        self._counted: set[str] = set()
        self._lock = threading.Lock()

    def refused(self, heliostat_id: str) -> None:
        """``heliostat_id``'s frame held no beam (its run will end ``no_beam``)."""
        self._count(heliostat_id, no_beam=True, beam_seen=False)

    def ended(self, run: RunRecord) -> None:
        """A heliostat's run ended: a beam seen (any measurement) resets the count."""
        self._count(run.heliostat_id, run.status == NO_BEAM, bool(run.measurements))

    def _count(self, heliostat_id: str, no_beam: bool, beam_seen: bool) -> None:
        with self._lock:
            if heliostat_id in self._counted:
                return
            self._counted.add(heliostat_id)
            if no_beam:
                self._row += 1
            elif beam_seen:
                self._row = 0

    @property
    def stopped(self) -> bool:
        with self._lock:
            return self._row >= self.stop_after

    def not_measured(self, heliostat_id: str, queue_index: int, now_s: float) -> RunRecord:
        """The record of a heliostat the stopped pass does not move."""
        return RunRecord(heliostat_id, queue_index, NO_BEAM, "idle", 0, start_s=now_s, end_s=now_s,
                         fault_cause=self.cause(heliostat_id, "not moved"))

    def cause(self, heliostat_id: str, what: str) -> str:
        return (f"{heliostat_id}: {what}: no beam on target {self.target} for {self._row} heliostats "
                f"in a row; {self._lamp_hint()}")

    def hold_back(self, cycles: Iterable) -> None:
        """The pass has stopped: the cycles already started whose beam has not gone onto the
        target yet (``WAITING``) park at standby by the fault path, which most of them are at
        already, and record ``no_beam``: a pipeline of K × depth heliostats would otherwise each
        put its beam on the target to find it dark. One that moves on meanwhile parks its beam
        from the target by the same path, unmeasured. Repeating it is harmless (a held-back
        cycle has its cause)."""
        for cyc in list(cycles):
            if cyc.state in WAITING and not (cyc.beam_on_target or cyc.measured or cyc.cause):
                cyc.no_beam = True
                cyc.request_abort(self.cause(cyc.ctx.heliostat_id, "not put on the target"))

    def _lamp_hint(self) -> str:
        src, lit = self.light_source, self.lit
        if lit is not None and lit.confirmed:
            return (f"light source {src} was confirmed lit by the lamp {lit.by} at {lit.utc}: check that it "
                    f"gives light (a confirmation input can say lit while the lamp is dark) and that the "
                    f"camera sees target {self.target}")
        return (f"check that light source {src} is lit and confirmed (it was not confirmed by a lamp "
                f"panel) and that the camera sees target {self.target}")


class RefusalObserver(CycleObserver):
    """Passes every hook on to ``inner`` and tells ``watch`` of a refused frame as its cycle
    enters *fault* (the machine has set ``no_beam``), before that cycle parks and releases the
    target: the refusal that stops the pass is counted, and the cycles waiting for the target
    held back, before the next one is admitted. ``cycles``: heliostat → its running cycle.
    Runs on the refused cycle's thread, inside its machine's lock; the cycles it holds back are
    in ``WAITING``, never in *fault*, so no two refused cycles wait for each other's lock."""

    def __init__(self, inner: CycleObserver, watch: NoBeamWatch, cycles: Mapping[str, Any]) -> None:
        self.inner, self.watch, self.cycles = inner, watch, cycles

    def state_changed(self, heliostat_id: str, state: str) -> None:
        self.inner.state_changed(heliostat_id, state)
        cyc = self.cycles.get(heliostat_id)
        if state == "fault" and cyc is not None and cyc.no_beam and cyc.fault_state not in WAITING:
            self.watch.refused(heliostat_id)
            if self.watch.stopped:
                self.watch.hold_back(self.cycles.values())

    def measured(self, heliostat_id: str, measurement: MeasurementRecord) -> None:
        self.inner.measured(heliostat_id, measurement)
