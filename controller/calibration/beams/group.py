"""One capture for several beams on a target, and whose spot is whose (``beams_per_target`` K > 1).

The heliostats holding the target's slots (:class:`controller.calibration.cycle.gate.TargetGate`)
meet at a *round* (:meth:`SharedCapture.capture`, called by each one's cycle in *capturing*):

1. the round forms when every heliostat on the target is settled at its slot and waits in
   *capturing*, and no further heliostat is about to take a free slot; one capture (frame 1)
   serves them all, and no newcomer is admitted until frame 2 (``TargetGate.held``). A round
   of one — its beam the only one on the target — is measured on frame 1 as with K = 1;
2. each steps by its own known amount (motor steps in its own direction, both axes moving up
   as the approach ended, so backlash stays taken up), settles, and a second capture (frame 2)
   is taken once all have;
3. each slot's window must hold a spot in both frames, and the slot's cell (slots.py, Eq. 2)
   must have moved by its own heliostat's predicted displacement (:func:`spots.window_shifts`,
   :func:`spots.confirm_by_step`). Its measurement is frame 1 at the pose of frame 1: its
   shape with everything outside its cell flattened, its centroid its cell's weighed energy
   (:class:`spots.Isolated`);
4. a heliostat whose spot is missing or ambiguous (every one, if a spot of the round is missing
   in frame 1), or reaches so far towards another slot that isolating it would cut it (its
   window's centroid moves more than ``SPILL_M`` without its border band there, ``spills``), is
   **measured again alone** (:meth:`TargetGate.acquire_alone`, no newcomer admitted meanwhile):
   the first stays while the others park, any further one parks and comes back. A
   measurement is never taken from a spot whose identity was not confirmed;
5. a heliostat that comes back for another look (a correction, a clipped spot) while another
   waits to be measured alone parks and is measured alone after it: the one waiting cannot
   take the target while this beam is on it, nor a round form while that one is not at it.

Corrections (a calibration campaign) repeat this per measurement with the other beams in place.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np

from controller.calibration.beams.identity import identity_step
from controller.calibration.beams.slots import IDENTITY_STEP_M
from controller.calibration.cycle.approach import approach_path
from controller.errors import HeliocalError
from controller.imaging import spots

# A spot whose window's energy centroid moves more than this when the window loses its border
# band on the sides facing another slot (:func:`controller.imaging.spots.spills`) reaches so far
# towards another spot that isolating it could bias its centroid by as much (≈ 1 mrad at 100 m):
# it is measured alone. Only what the centroid weighs counts; smaller spills (a streaked spot's
# tail) are kept: measuring them alone cost a quarter of the rounds' gain (docs/campaigns.md).
SPILL_M = 0.1
# The energy a cell's measurement weighs must move with its heliostat's step: a spot cut by its
# cell moves less than the step, not across it (≤ 0.04 m of a 0.3 m step on the simulated plant's
# nights); energy moving with another step — another heliostat's spot on this one — pulls it
# across (0.155 m, tests/calibration/beams/test_beams_sim.py). A fraction of the layout's step.
ACROSS = 0.25


@dataclass
class _Round:
    members: dict[int, tuple[np.ndarray, np.ndarray]]  # ticket -> (slot uv m, predicted step uv m)
    frame1: Any = None
    frame2: Any = None
    stepped: set[int] = field(default_factory=set)
    left: set[int] = field(default_factory=set)
    second_started: bool = False
    failed: bool = False  # a capture of the round failed: every member leaves it
    assigned: dict[int, int | None] | None = None
    stays: int | None = None  # the member measured alone where it stands, the others gone
    level: float | None = None  # frame 1's background b (imaging.spots.Excess)
    windows: list[tuple[int, int, int, int]] | None = None  # where each spot is looked for
    cells: list[tuple[int, int, int, int]] | None = None  # where each is measured (slots.py, Eq. 2)
    centres: list[np.ndarray] | None = None  # each cell's weighed energy centroid, px, in frames 1 and 2


def slot_parks(pointing, slot: int, k: int, frame, current: tuple[int, int] | None,
               step_m: float = IDENTITY_STEP_M) -> bool:
    """Can a heliostat aimed at its slot by ``pointing`` take it and be parked safely: its aim
    and its identity-stepped pose inside the soft limits, and a safe slew to its standby pose
    (:meth:`BeamSafety.path_to`) from where it stands now (``current``), from its aim and from
    the stepped pose? A heliostat for which it cannot keeps its planned aim and takes the
    target alone (``TargetGate.solo``)."""
    try:
        aim = pointing.aim_steps(pointing.model)
        standby = pointing.standby_steps(pointing.model)
        step, _ = identity_step(pointing, aim, slot, k, frame, step_m)
        stepped = (aim[0] + step[0], aim[1] + step[1])
        pointing.kin.azimuth.check(stepped[0], "the identity step")
        pointing.kin.elevation.check(stepped[1], "the identity step")
        pointing.warm_paths((current, aim, stepped), standby)
        for pose in (p for p in (current, aim, stepped) if p is not None):
            pointing.path_to(pose, standby)
    except (HeliocalError, ValueError):  # out of reach, or no safe slew
        return False
    return True


class SharedCapture:
    """The rounds of one target's campaign (module docstring). ``capture()`` takes one frame
    pair from the target's camera (serialised by the campaign), ``merge`` makes its HDR image,
    ``frame`` maps pixels to the target (a ``TargetFrame``), ``layout`` the slots (``SlotLayout``);
    ``step_settle_s``: the settling after the identity step (``calibration.identity_settle_s``);
    ``floor``: the centroid threshold (``calibration.centroid_threshold``, :data:`SPILL_M`)."""

    def __init__(self, gate, capture, merge, frame, layout, step_settle_s: float, floor: float) -> None:
        self.gate = gate
        self.layout = layout
        self._capture = capture
        self._merge = merge
        self._merged: tuple[Any, np.ndarray] | None = None  # the last frame merged and its HDR image
        self.frame = frame
        self.step_settle_s = step_settle_s
        self.floor = floor
        self._round: _Round | None = None
        self._ready: set[int] = set()
        self._lock = threading.Lock()  # the round's identification, computed once
        self.rounds = 0
        self.alone: list[str] = []  # heliostats measured again alone (ambiguous or missing spot)

    def merge(self, frame) -> np.ndarray:
        """``frame``'s HDR image: a round's frame 1, merged to tell its spots apart, is not merged
        again for each of its members (the cycles' ``merge``)."""
        last = self._merged
        if last is not None and last[0] is frame:
            return last[1]
        hdr = self._merge(frame)
        self._merged = (frame, hdr)
        return hdr

    # -- geometry -------------------------------------------------------------------------------
    def uv(self, enu) -> np.ndarray:
        rel = np.asarray(enu, float) - self.frame.center
        return np.array([rel @ self.frame.u, rel @ self.frame.v])

    def window(self, rect_m) -> tuple[int, int, int, int]:
        """The pixels (r0, r1, c0, c1, half-open) of the rectangle ``rect_m`` (u0, u1, v0, v1) m
        from the target centre: a slot's search window or its cell (slots.py, Eq. 1, 2)."""
        f = self.frame
        rows, cols = f.shape
        du, dv = f.width_m / cols, f.height_m / rows
        u0, u1, v0, v1 = (float(x) for x in rect_m)
        c0, c1 = ((u + f.width_m / 2) / du - 0.5 for u in (u0, u1))
        r0, r1 = ((v + f.height_m / 2) / dv - 0.5 for v in (v0, v1))
        return (max(0, math.floor(r0)), min(rows, math.ceil(r1) + 1),
                max(0, math.floor(c0)), min(cols, math.ceil(c1) + 1))

    def _facing(self, ticket: int) -> tuple[bool, bool, bool, bool]:
        """Which sides of ``ticket``'s window (first rows, last rows, first columns, last columns:
        v0, v1, u0, u1) face another slot rather than the view's edge (its cell's, slots.py Eq. 2)."""
        u0, u1, v0, v1 = self.layout.cells_m[self.gate.slot(ticket)]
        hu, hv = self.frame.width_m / 2.0, self.frame.height_m / 2.0
        return v0 > -hv, v1 < hv, u0 > -hu, u1 < hu

    def _uvs(self, px) -> np.ndarray:
        """(n, 2) px (x, y) → (n, 2) m (u, v) on the target; NaN stays NaN."""
        return np.array([self.uv(self.frame.pixel_to_enu(x, y)) if np.isfinite(x + y) else (np.nan, np.nan)
                         for x, y in px]).reshape(-1, 2)

    def _pixel_m(self) -> float:
        """The size of the view's pixels on the target, m (the smaller side)."""
        rows, cols = self.frame.shape
        return min(self.frame.width_m / cols, self.frame.height_m / rows)

    def _max_shift_px(self) -> int:
        """The largest shift searched between a round's captures: twice the identity step."""
        return math.ceil(2.0 * self.layout.step_m / self._pixel_m())

    def identity_step(self, cyc) -> tuple[tuple[int, int], np.ndarray]:
        """:func:`identity_step` of ``cyc``'s heliostat at its present pose and slot."""
        rank = self.layout.rank(self.gate.slot(cyc._ticket))  # its place in its tier
        return identity_step(cyc.ctx.pointing, (cyc.az, cyc.el), *rank, self.frame, self.layout.step_m)

    def hand_over(self, cyc):
        """A drive watch for ``cyc``'s park after its measurement: its slot goes to the next heliostat
        (:meth:`TargetGate.vacate`) once its beam is off the target, margin included, read every polling
        period until then (``BeamSafety.beam_on_target``; True: ``Drive.wait_in_position``); the park
        path never brings it back (``BeamSafety.path_to``), so the rest of the park's polls trace no ray."""
        left = False

        def watch(st) -> bool:
            nonlocal left
            if not left and not cyc.ctx.pointing.beam_on_target(st.az_steps, st.el_steps):
                left = True
                self.gate.vacate(cyc._ticket)
            return not left
        return watch

    # -- the round ---------------------------------------------------------------------------
    def _fires(self) -> bool:
        g = self.gate
        if self._round is not None or not g.holders or not g.holders <= self._ready or g.leaving:
            return False  # a leaving beam may still be in the view: it parks first
        return not any(g.admissible(t) for t in g.waiting)

    def capture(self, cyc):
        """Frame 1 of this heliostat's round and a function isolating its spot in the HDR image
        (None when it was measured alone); module docstring."""
        g, ticket = self.gate, cyc._ticket
        if g.alone == ticket or ticket in g.solo:  # measured alone (a correction, a clipped spot, solo)
            return self._capture(), None
        cancelled = lambda: cyc.state != "capturing"  # noqa: E731
        pose = (cyc.az, cyc.el)
        step, disp = self.identity_step(cyc)
        slot_uv = self.uv(cyc.ctx.pointing.aim_point)
        leader = False
        with g.cv:
            self._ready.add(ticket)
            g.cv.notify_all()
            try:
                while True:
                    rnd = self._round
                    if rnd is not None and ticket in rnd.members and ticket not in rnd.left:
                        break  # a round it left (a correction's next look) is not joined again
                    if g.others_alone(ticket):  # it waits for this beam to leave: go, be measured alone
                        rnd = None
                        break
                    if self._fires():  # every beam on the target waits here: one capture for all
                        rnd = self._round = _Round(dict.fromkeys(g.holders))
                        g.held = leader = True  # no newcomer slews across the target meanwhile
                        break
                    cyc._check_current("capturing")
                    g.cv.wait(0.02)
            finally:
                self._ready.discard(ticket)
            if rnd is not None:
                rnd.members[ticket] = (slot_uv, disp)
        if rnd is None:
            return self._alone(cyc, pose), None
        if leader and len(rnd.members) == 1:  # its beam alone on the target: measured as with K = 1
            try:
                frame1 = self._capture()
                with g.cv:
                    self.rounds += 1
            finally:
                self._leave(rnd, ticket)
            return frame1, None
        try:
            if leader:
                frame1 = self._capture()
                with g.cv:
                    rnd.frame1 = frame1
                    self.rounds += 1
                    g.cv.notify_all()
            with g.cv:
                while rnd.frame1 is None:
                    if rnd.failed or cancelled():
                        raise _Left
                    g.cv.wait(0.02)
            if cancelled():
                raise _Left
            cyc._move("capturing", pose[0] + step[0], pose[1] + step[1])
            # Frame 2 only tells which spot moved, to a few cm (Eq. 1), and is never measured.
            cyc._wait("capturing", min(self.step_settle_s, cyc.ctx.settle_s))
        except BaseException:
            if leader and rnd.frame1 is None:
                rnd.failed = True
            self._leave(rnd, ticket, stepped=True)
            raise
        try:
            self._second(rnd, ticket, cancelled)
        except BaseException:
            self._leave(rnd, ticket)
            raise
        try:
            with cyc.ctx.time.computing():  # the controller's own computing, as in merging
                label = self._identify(rnd, ticket)
        finally:
            self._leave(rnd, ticket)
        if label is not None:
            cyc.az, cyc.el = pose  # the measurement is frame 1's, at frame 1's pose
            x, y = rnd.centres[0][label]  # measured where its cell's energy lies (spots.Isolated)
            return rnd.frame1, spots.Isolated(rnd.windows, rnd.cells[label], rnd.level, (x, y),
                                              tuple(self.frame.pixel_to_enu(x, y)))
        if rnd.stays == ticket:
            return self._alone_here(cyc, pose), None
        cyc.az, cyc.el = pose
        return self._alone(cyc, pose), None

    def _second(self, rnd: _Round, ticket: int, cancelled) -> None:
        g = self.gate
        with g.cv:
            rnd.stepped.add(ticket)
            g.cv.notify_all()
            while rnd.frame2 is None:
                if not rnd.second_started and set(rnd.members) <= rnd.stepped | rnd.left:
                    rnd.second_started = True
                    break
                if rnd.failed or cancelled():
                    raise _Left
                g.cv.wait(0.02)
            else:
                return
        try:
            frame2 = self._capture()
        except BaseException:
            rnd.failed = True
            raise
        with g.cv:  # nobody is admitted until the round is identified (_identify)
            rnd.frame2 = frame2
            g.cv.notify_all()

    def _identify(self, rnd: _Round, ticket: int) -> int | None:
        with self._lock:
            if rnd.assigned is None:
                tickets = sorted(t for t, v in rnd.members.items() if v is not None)
                r = self.layout.reach_m[[self.gate.slot(t) for t in tickets]] + self.layout.step_m
                rnd.windows = win = [self.window(np.repeat(rnd.members[t][0], 2) + [-ru, ru, -rv, rv])
                                     for t, (ru, rv) in zip(tickets, r, strict=True)]
                rnd.cells = [self.window(self.layout.cells_m[self.gate.slot(t)]) for t in tickets]
                # Each capture merged, smoothed and levelled once for the four uses below (frame
                # 1's HDR image kept for the members' own analysis, merge).
                hdr = [spots.excess(self.merge(rnd.frame1), win), spots.excess(self._merge(rnd.frame2), win)]
                rnd.level = hdr[0].b
                here, there = spots.window_spots(hdr[0], win), spots.window_spots(hdr[1], win)
                moved = here + spots.window_shifts(hdr[0], hdr[1], rnd.cells, self._max_shift_px(), win)
                moved[~np.isfinite(there).all(axis=1)] = np.nan  # a spot in both captures
                steps = np.array([rnd.members[t][1] for t in tickets])
                facing, floor = [self._facing(t) for t in tickets], self.floor
                spill = spots.spills(hdr[0], win, facing, floor) * self._pixel_m()
                rnd.centres = [spots.cell_centroids(h, rnd.cells, win, floor) for h in hdr]
                weighed = [self._uvs(c) for c in rnd.centres]
                across = spots.moved_across(*weighed, steps)
                # A spot missing from its window in frame 1 is elsewhere, maybe in another's cell.
                whole = bool(np.isfinite(here).all())
                confirmed = spots.confirm_by_step(self._uvs(here), self._uvs(moved), steps)
                ok = [whole and a and bool(b <= SPILL_M) and bool(c <= ACROSS * self.layout.step_m)
                      for a, b, c in zip(confirmed, spill, across, strict=True)]
                rnd.assigned = {t: (k if ok[k] else None) for k, t in enumerate(tickets)}
                with self.gate.cv:  # the first to be measured alone stays; no newcomer before it
                    rnd.stays = min((t for t, k in rnd.assigned.items() if k is None), default=None)
                    if rnd.stays is not None:
                        self.gate.reserve_alone(rnd.stays)
                    self.gate.held = False
                    self.gate.changed()
            return rnd.assigned.get(ticket)

    def _leave(self, rnd: _Round, ticket: int, stepped: bool = False) -> None:
        g = self.gate
        with g.cv:
            if stepped:
                rnd.stepped.add(ticket)
            rnd.left.add(ticket)
            if set(rnd.members) <= rnd.left and self._round is rnd:
                self._round = None
                g.held = False
            g.changed()

    def _alone_here(self, cyc, pose: tuple[int, int]):
        """Step back to ``pose`` while the others park (backlash taken up again), take the target
        alone once every other beam is parked, capture: no park and approach of its own."""
        self._approach(cyc, pose)
        return self._capture_alone(cyc)

    def _alone(self, cyc, pose: tuple[int, int]):
        """Park, give the slot back, take the target alone, come back to ``pose``, capture."""
        cyc._park("capturing")
        cyc.beam_on_target = False
        self.gate.give_back(cyc._ticket)
        return self._capture_alone(cyc, partial(self._approach, cyc, pose))

    def _capture_alone(self, cyc, then=None):
        """Take the target alone (:meth:`TargetGate.acquire_alone`), ``then()``, capture."""
        if not self.gate.acquire_alone(cyc._ticket, lambda: cyc.state != "capturing"):
            cyc._check_current("capturing")
            raise RuntimeError("target blocked: another heliostat's beam may still be on it")
        self.alone.append(cyc.ctx.heliostat_id)
        if then is not None:
            then()
        return self._capture()

    @staticmethod
    def _approach(cyc, pose: tuple[int, int]) -> None:
        """Onto ``pose`` ending up on both axes (backlash), settled."""
        cyc.beam_on_target = True
        for waypoint in approach_path(cyc.at, pose, cyc.ctx.backlash_steps, cyc.ctx.drive.limits):
            cyc._move("capturing", *waypoint)
        cyc.az, cyc.el = pose
        cyc._wait("capturing", cyc.ctx.settle_s)


class _Left(Exception):
    """This heliostat left its round (its cycle was stopped)."""
