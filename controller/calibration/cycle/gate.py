"""Beams on the target: handed out in queue order, one at a time — or, under a lamp at night
with ``calibration.beams_per_target`` K > 1, up to K at once, each at its own slot."""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping, Sequence, Set

# Wall seconds between a waiting ticket's checks of ``cancelled``: whatever may admit a ticket
# notifies the waiters (TargetGate.changed), so this only bounds how late a cycle that timed out
# or was aborted while waiting notices it. At 0.05 s two dozen cycles waiting at once (a night
# of three targets, K = 4) woke some 500 times a wall second between them.
POLL_S = 0.5

class TargetGate:
    """Hands the target to heliostats in queue order (tickets 0, 1, 2, …), ``beams`` at a time.

    ``acquire(ticket)`` with K = 1 blocks until every smaller ticket acquired the target and
    released it (or was skipped): one beam at a time, in queue order. With ``beams`` K > 1
    ticket t uses its slot (:meth:`slot`: ``slots[t]``, by default ``t mod K``), which only one
    beam holds at a time: it waits only for the ticket before it at that slot to release it
    (and for no holder to be at that slot, should that one have been skipped), so a heliostat
    still slewing to standby holds up its own slot, not the others. ``conflicts`` (slot → slots,
    itself included; :meth:`controller.calibration.beams.slots.SlotLayout.conflicts`): slots of
    different tiers whose cells overlap; a ticket then also waits for the last ticket before it
    at each of those, and is admitted only while none of them is held.
    ``acquire_alone(ticket)``: for a heliostat measured again alone (its spot could not be told
    from the others): waits until no other beam holds the target and keeps every other ticket
    off it until released; it goes before tickets not yet admitted, and the tickets to be
    measured alone go in the order they asked (:meth:`reserve_alone` first: its beam already
    waits on the target).
    A ticket in ``solo`` (its slot None: no slot's pose suits its heliostat) is admitted only
    onto an empty target and keeps every other ticket off it while it holds it.
    ``together``: the first round's tickets (the first at each slot) are admitted only once
    each of them waits at standby (or ended): their beams then go onto the target at the same
    time instead of the first ones waiting there, their beams on it, for the last to come.
    ``held``: while True (a round's captures are being taken) no ticket is admitted, so no
    beam slews across the target during an exposure.
    ``vacate(ticket)`` (K > 1 only): the ticket's beam, on its way to standby, has left the
    target (:meth:`controller.calibration.cycle.machine.CalibrationCycle.do_standby`): its slot goes to
    ticket t + K at once while it goes on parking; until it is parked it is ``leaving``, and no
    round is captured nor anyone taken alone meanwhile.
    ``blocked`` becomes True when a beam may have been left on the target, after which nobody
    gets the target again.
    """

    def __init__(self, beams: int = 1, together: bool = False, slots: Sequence[int | None] = (),
                 conflicts: Mapping[int, Set[int]] | None = None) -> None:
        if beams < 1:
            raise ValueError(f"beams per target must be at least 1, got {beams}")
        self.beams = beams
        self._lock = threading.RLock()
        # A round's members wait on cv (group.py); each ticket waiting for its turn waits on a
        # condition of its own on the same lock, woken by changed() only when it may go on
        # (admitted, blocked or cancelled). With one condition for every waiting ticket, the
        # two dozen cycles waiting on a target of a 10,000-heliostat night (3 targets, K = 4)
        # were all woken by every change, to be put back to sleep (docs/architecture.md).
        self.cv = threading.Condition(self._lock)
        self._turns: dict[int, tuple[threading.Condition, Callable[[], bool]]] = {}
        self._next = 0  # the next ticket to admit, in queue order
        self._done: set[int] = set()
        self.holders: set[int] = set()
        self.alone: int | None = None  # the ticket measured alone now
        self._alone_waiting: list[int] = []  # in the order they asked (reserve_alone, acquire_alone)
        self.waiting: set[int] = set()  # tickets blocked in acquire
        self.solo = {t for t, s in enumerate(slots) if s is None}  # no slot fits them: the target alone
        self._slots = list(slots)
        self._near = {s: frozenset(c) for s, c in (conflicts or {}).items()}
        # ticket -> the last tickets before it at its slot and at the slots conflicting with it
        self._before: dict[int, tuple[int, ...]] = {}
        last: dict[int, int] = {}
        for t, s in enumerate(self._slots):
            if s is not None:
                self._before[t] = tuple(last[c] for c in sorted(self._near.get(s, {s})) if c in last)
                last[s] = t
        self.held = False
        self.blocked = False
        self._vacated: set[int] = set()
        # Vacated and not yet released: kept as it changes, not as _vacated - _done, which grows
        # with the pass (1,300 tickets a pass in a 10,000-heliostat night) and is asked at every
        # round member's wake-up.
        self._leaving: set[int] = set()
        first = [t for t, b in self._before.items() if not b] if self._slots else range(beams)
        self._together = set(first) if together else set()

    @property
    def holder(self) -> int | None:
        """The one holder (K = 1), or None."""
        return next(iter(self.holders), None) if len(self.holders) == 1 else None

    def slot(self, ticket: int) -> int:
        """The slot (0 … K − 1) of ``ticket``: its aim point on the target."""
        s = self._slots[ticket] if ticket < len(self._slots) else None
        return ticket % self.beams if s is None else s

    def admissible(self, ticket: int) -> bool:
        """Could ``ticket`` take the target now (the caller holds ``cv``)?"""
        if self.blocked or self.held or self.alone is not None or self._alone_waiting \
                or self.holders & self.solo:
            return False
        if ticket in self._together and not all(t in self.waiting or t in self._done or t in self.holders
                                                for t in self._together):
            return False
        if ticket in self.solo:  # its capture is taken as it arrives: every other beam parked
            return not self.holders and not self.leaving
        before = self._before.get(ticket, (ticket - self.beams,) if ticket >= self.beams else ())
        near = self._near.get(self.slot(ticket), {self.slot(ticket)})
        return ((self.beams > 1 or self._next == ticket) and len(self.holders) < self.beams
                and all(b in self._done or b in self._vacated for b in before)
                # the one before may have been skipped while the one before it still holds the slot
                and all(self.slot(h) not in near for h in self.holders))

    def changed(self) -> None:
        """Something that may admit a ticket or fire a round changed (the caller holds ``cv``):
        wake the tickets waiting for a turn that may go on now, and a round's members."""
        for turn, ready in self._turns.values():
            if ready():
                turn.notify()
        self.cv.notify_all()

    def _wait_turn(self, ticket: int, may_go: Callable[[], bool], cancelled: Callable[[], bool],
                   poll_s: float) -> None:
        """Wait (holding ``cv``) until :meth:`changed` finds that ``ticket`` may go on (``may_go()``,
        blocked or ``cancelled()``), or ``poll_s`` passed."""
        turn = threading.Condition(self._lock)
        self._turns[ticket] = (turn, lambda: self.blocked or cancelled() or may_go())
        try:
            turn.wait(poll_s)
        finally:
            del self._turns[ticket]

    @property
    def leaving(self) -> set[int]:
        """Tickets whose beam left the target (:meth:`vacate`) and that are not parked yet."""
        return set(self._leaving)

    def acquire(self, ticket: int, cancelled: Callable[[], bool], poll_s: float = POLL_S) -> bool:
        with self.cv:
            self.waiting.add(ticket)
            # A round may wait for this one (cv); a first-round ticket too, if it is one of them.
            if ticket in self._together:
                self.changed()
            else:
                self.cv.notify_all()
            try:
                while not self.admissible(ticket):
                    if cancelled() or self.blocked:
                        return False
                    self._wait_turn(ticket, lambda: self.admissible(ticket), cancelled, poll_s)
                    # Held back while it waited (a pass stopped), it may be woken by the very
                    # release that would admit it, before its own poll would have seen it.
                    if cancelled():
                        return False
                self.holders.add(ticket)
                self._next += 1
                while self._next in self._done:
                    self._next += 1
                # A holder more admits no other ticket (it was waiting, for the first round's
                # rule): only a round's members need to know.
                self.cv.notify_all()
                return True
            finally:
                self.waiting.discard(ticket)

    def acquire_alone(self, ticket: int, cancelled: Callable[[], bool], poll_s: float = POLL_S) -> bool:
        """Take the target with no other beam on it (module docstring); the ticket must have
        given its slot back first (:meth:`give_back`)."""
        with self.cv:
            self._ask_alone(ticket)
            try:
                while not self._alone_now(ticket):
                    if cancelled() or self.blocked:
                        return False
                    self._wait_turn(ticket, lambda: self._alone_now(ticket), cancelled, poll_s)
                    if cancelled():  # as in acquire
                        return False
                self.alone = ticket
                return True
            finally:
                self._forget_alone(ticket)
                self.changed()

    def _alone_now(self, ticket: int) -> bool:
        """May ``ticket`` take the target alone now (the caller holds ``cv``)?"""
        return not (self.holders - {ticket} or self.leaving or self.alone is not None
                    or self._alone_waiting[0] != ticket)

    def others_alone(self, ticket: int) -> bool:
        """Is another ticket measured alone now, or waiting to be? (the caller holds ``cv``) A
        holder must then leave the target before its next capture: a round cannot form while
        that one waits, nor the one waiting take the target while this one's beam is on it."""
        return self.alone not in (None, ticket) or any(t != ticket for t in self._alone_waiting)

    def _ask_alone(self, ticket: int) -> None:
        if ticket not in self._alone_waiting:
            self._alone_waiting.append(ticket)

    def _forget_alone(self, ticket: int) -> None:
        if ticket in self._alone_waiting:
            self._alone_waiting.remove(ticket)

    def reserve_alone(self, ticket: int) -> None:
        """``ticket`` is to be measured alone where it stands (it holds its slot): nobody is
        admitted from now on until it has been (:meth:`acquire_alone`)."""
        with self.cv:
            self._ask_alone(ticket)

    def vacate(self, ticket: int) -> None:
        """``ticket``'s beam has left the target while it parks (class docstring): its slot is free."""
        with self.cv:
            if (ticket in self.holders or self.alone == ticket) and self.beams > 1:
                self.holders.discard(ticket)
                if self.alone == ticket:
                    self.alone = None
                self._vacated.add(ticket)
                self._leaving.add(ticket)
                self.changed()

    def give_back(self, ticket: int, beam_off_target: bool = True) -> None:
        """Give the slot back without ending the ticket (its beam parked, to be measured alone)."""
        with self.cv:
            if not beam_off_target:
                self.blocked = True
            self.holders.discard(ticket)
            self.changed()

    def release(self, ticket: int, beam_off_target: bool = True) -> None:
        """Give the target back (or skip this ticket if it never held it)."""
        with self.cv:  # re-entrant: give_back takes it again
            self.give_back(ticket, beam_off_target)
            if self.alone == ticket:
                self.alone = None
            self._forget_alone(ticket)  # reserved, then stopped before its turn
            self._done.add(ticket)
            self._leaving.discard(ticket)
            if self._next == ticket:  # skipped before its turn came
                while self._next in self._done:
                    self._next += 1
            self.changed()
