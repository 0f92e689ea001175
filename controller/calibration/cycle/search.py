"""The beam search of one cycle (``calibration.search``, docs/commissioning.md "First light on a
new field"): when a look finds no spot in the camera's view, the cycle aims at the next point of
the pattern around where its model (the nominal one for a new heliostat) and the field put the
beam (:meth:`controller.calibration.cycle.pointing.GeometryPointing.search_pattern`), each pose
and the slew to it checked by beam safety first (a point refused is skipped), until a spot is in
view or ``max_looks`` looks were taken; what it did goes into the run's
:class:`controller.calibration.records.SearchRecord`. A point whose pose is refused is looked at
half a step aside if that is safe; one whose slew from the present look is refused, again after
the next look.

What the field already knows (:class:`FieldMisses`): the heliostats of a new field share much of
their error (mounting, survey), so once :data:`MIN_FOUND` heliostats of a campaign were found,
the median of their misses (as angles of the reflected beam) is where the next ones start, and
the misses' scatter about it how far they park and search.

Only under a lamp and for one beam on the target (no slots): a search under the sun would sweep
concentrated sunlight over the tower.

Units: m in the target plane (u, v of the camera's view), beam angles mrad, motor steps,
plant-clock s.
"""

from __future__ import annotations

import math
import threading

import numpy as np

from controller.calibration.cycle.observations import NoBeam
from controller.calibration.records import ModelRecord, SearchRecord

MIN_FOUND = 3  # heliostats found before their misses move the others' start


class FieldMisses:
    """The misses of the heliostats found so far (beam angles, mrad: miss m / distance m × 1000,
    along u and v), thread-safe. Once :data:`MIN_FOUND` are in: the expected miss is their median
    per axis, its 1-σ their RMS about it (the larger axis) times √(1 + 1/n), for the few found."""

    def __init__(self) -> None:
        self._misses: list[tuple[float, float]] = []
        self._lock = threading.Lock()

    def add(self, miss_m: tuple[float, float], distance_m: float) -> None:
        with self._lock:
            self._misses.append((1e3 * miss_m[0] / distance_m, 1e3 * miss_m[1] / distance_m))

    def expected(self) -> tuple[tuple[float, float], float] | None:
        """((u, v) mrad, σ mrad) of the next heliostat's miss; None before :data:`MIN_FOUND`."""
        with self._lock:
            m = np.asarray(self._misses, float)
        if len(m) < MIN_FOUND:
            return None
        centre = np.median(m, axis=0)
        rms = float(np.sqrt(np.mean((m - centre) ** 2, axis=0)).max())
        return (float(centre[0]), float(centre[1])), rms * math.sqrt(1.0 + 1.0 / len(m))


def cycle_search(ctx) -> SpotSearch | None:
    """The beam search of a cycle's context (:class:`controller.calibration.cycle.context.CycleContext`):
    a pointing with one, under a lamp, one beam on the target, not a planned observation."""
    p = ctx.pointing
    if getattr(p, "search", None) is None or p.source_pos is None or ctx.group is not None \
            or ctx.observe_only:
        return None
    return SpotSearch(p, ctx.model, p.search.max_looks)


class SpotSearch:
    """The search state of one cycle: ``pointing`` (a GeometryPointing with a search), the
    model the cycle aims with, the search's look budget."""

    def __init__(self, pointing, model: ModelRecord | None, max_looks: int) -> None:
        self.pointing = pointing
        self.model = model
        self.max_looks = max_looks
        self.record = SearchRecord()
        self.offset = (0.0, 0.0)  # where the present look aims, m from the aim point
        self._pattern: np.ndarray | None = None
        self._next = 1  # the pattern's first point is the cycle's first look
        self._retry: list[tuple[tuple[float, float], int]] = []  # (offset, looks when its slew was refused)
        self._t0: float | None = None

    def first_pose(self, aim: tuple[int, int]) -> tuple[int, int]:
        """The pose of the first look: the aim, or where the field's misses say the beam is
        (the pattern's first point) when that pose is beam-safe."""
        self._pattern = self.pointing.search_pattern(self.model)
        pose = aim
        if len(self._pattern) and np.any(self._pattern[0] != 0.0):
            start = (float(self._pattern[0][0]), float(self._pattern[0][1]))
            pose = self.pointing.search_pose(start, self.model, None) or aim
            self.offset = start if pose != aim else (0.0, 0.0)
        self.record.offsets_m.append((round(self.offset[0], 3), round(self.offset[1], 3)))
        return pose

    def next_pose(self, at: tuple[int, int] | None, now_s: float) -> tuple[int, int] | None:
        """The pose of the next look (its offset in :attr:`offset`), or None when the budget or
        the pattern is used up (the plant time spent is then recorded). A point whose pose is
        safe but not the slew there from where the beam is now is tried again after the next
        look (from elsewhere), once; a point refused for good is counted in ``skipped``."""
        if self._t0 is None:
            self._t0 = now_s
        if self._pattern is None:
            self._pattern = self.pointing.search_pattern(self.model)
        rec = self.record
        while rec.looks < self.max_looks:
            due = [k for k, (_, looks) in enumerate(self._retry) if looks < rec.looks]
            if due or (self._retry and self._next >= len(self._pattern)):
                off, retried = self._retry.pop(due[0] if due else 0)[0], True
            elif self._next < len(self._pattern):
                u, v = self._pattern[self._next]
                off, retried = (float(u), float(v)), False
                self._next += 1
            else:
                break
            pose = self.pointing.search_pose(off, self.model, at)
            if pose is None:
                if self.pointing.search_pose(off, self.model, None) is None:
                    off, pose = self._nudged(off, at)  # the pose itself refused: half a step aside
                elif not retried:
                    self._retry.append((off, rec.looks))
                    continue
            if pose is None:
                rec.skipped += 1
                continue
            rec.looks += 1
            rec.offsets_m.append((round(off[0], 3), round(off[1], 3)))
            self.offset = off
            return pose
        rec.seconds = now_s - self._t0
        return None

    def _nudged(self, off: tuple[float, float], at) -> tuple[tuple[float, float], tuple[int, int] | None]:
        """A pattern point whose pose beam safety refuses, moved half a step along u or v (the
        side away from the refused area first) to a pose it accepts: the look still covers most of
        the point's cell (a cell beside another target is otherwise never looked at)."""
        su, sv = self.pointing.search_step_m
        for du, dv in ((0.5 * su, 0.0), (-0.5 * su, 0.0), (0.0, -0.5 * sv), (0.0, 0.5 * sv)):
            moved = (off[0] + du, off[1] + dv)
            pose = self.pointing.search_pose(moved, self.model, at)
            if pose is not None:
                return moved, pose
        return off, None

    def next_look(self, at: tuple[int, int] | None, now_s: float, missed: Exception) -> tuple[int, int]:
        """:meth:`next_pose`; :class:`NoBeam` naming ``missed`` (the last look's refusal) and where
        it searched when the search is spent."""
        pose = self.next_pose(at, now_s)
        if pose is None:
            raise NoBeam(f"{missed}; {self.summary()}", getattr(missed, "statistic", 0.0),
                         getattr(missed, "threshold", 0.0))
        return pose

    def seen(self, centroid_enu, now_s: float) -> str:
        """A spot is in view at the present look: where the starting pose's beam landed (the
        centroid less the look's offset), the search's time, told to the field's misses (a
        heliostat without a model); once. Returns the cycle's next trigger, ``analysed``."""
        rec = self.record
        if rec.found:
            return "analysed"
        rec.found = True
        rec.seconds = 0.0 if self._t0 is None else now_s - self._t0
        p = self.pointing
        d = np.asarray(centroid_enu, float) - p.aim_point
        rec.miss_m = (round(float(d @ p.frame.u) - self.offset[0], 3),
                      round(float(d @ p.frame.v) - self.offset[1], 3))
        if self.model is None and getattr(p, "field_misses", None) is not None:
            p.field_misses.add(rec.miss_m, float(np.linalg.norm(p.aim_point - p.heliostat_pos)))
        return "analysed"

    def summary(self) -> str:
        """Where it searched, for the run's cause."""
        rec = self.record
        us = [o[0] for o in rec.offsets_m] or [0.0]
        vs = [o[1] for o in rec.offsets_m] or [0.0]
        return (f"beam search: no spot in view in {rec.looks + 1} looks over u {min(us):+.1f} … "
                f"{max(us):+.1f} m, v {min(vs):+.1f} … {max(vs):+.1f} m about the aim point ({rec.skipped} "
                f"points refused by beam safety or out of reach, {rec.seconds:.0f} s)")
