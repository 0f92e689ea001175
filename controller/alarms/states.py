"""An alarm's state as ISA-18.2 / IEC 62682 define it, and the operations that change it.

An alarm is *active* while its condition holds and *acknowledged* once an operator said so; the
two give its state:

=================  =======  ==============  ===========================================
state              active   acknowledged    meaning
=================  =======  ==============  ===========================================
``unack_active``   yes      no              new: annunciated until someone acknowledges
``ack_active``     yes      yes             known, the condition still holds
``unack_rtn``      no       no              returned to normal before anyone acknowledged
``normal``         no       yes             nothing to do
=================  =======  ==============  ===========================================

``shelved`` overrides them while an operator's shelve has not expired: the alarm is kept and
its history written, but it is not annunciated. A condition that returns while its alarm is
active changes nothing; once it had cleared, it activates the same alarm again and counts it
(``count``): a chattering alarm is counted, not repeated. The operations here are pure: they
return the changed alarm, or None when nothing changes; the store writes it with its event.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from datetime import UTC, datetime, timedelta

from controller.alarms.conditions import condition
from controller.errors import InputError

STATES = ("unack_active", "ack_active", "unack_rtn", "normal", "shelved")
EVENT_KINDS = ("raised", "cleared", "acknowledged", "shelved", "unshelved")
MAX_SHELVE = timedelta(days=7)  # a shelved alarm comes back within a week at the latest


@dataclass(frozen=True)
class Alarm:
    """One alarm (one condition on one object). Times are ISO 8601 UTC stamps; ``raised_utc``
    is its latest activation, ``count`` how many times it activated."""

    condition: str
    source: str
    message: str
    active: bool
    acked: bool
    raised_utc: str
    count: int = 1
    cleared_utc: str | None = None
    acked_utc: str | None = None
    acked_by: str | None = None
    ack_comment: str | None = None
    shelved_until_utc: str | None = None
    shelved_by: str | None = None
    id: int | None = None

    @property
    def priority(self) -> str:
        return condition(self.condition).priority

    @property
    def severity(self) -> int:
        return condition(self.condition).severity

    def shelved(self, now: datetime) -> bool:
        return self.shelved_until_utc is not None and now < datetime.fromisoformat(self.shelved_until_utc)

    def state(self, now: datetime) -> str:
        """One of :data:`STATES` at ``now``."""
        if self.shelved(now):
            return "shelved"
        if self.active:
            return "ack_active" if self.acked else "unack_active"
        return "normal" if self.acked else "unack_rtn"

    def to_json(self, now: datetime) -> dict:
        return {"id": self.id, "condition": self.condition, "source": self.source, "priority": self.priority,
                "severity": self.severity, "state": self.state(now), "active": self.active,
                "acknowledged": self.acked, "message": self.message, "raised_utc": self.raised_utc,
                "cleared_utc": self.cleared_utc, "count": self.count, "acknowledged_by": self.acked_by,
                "acknowledged_utc": self.acked_utc, "ack_comment": self.ack_comment,
                "shelved_until_utc": self.shelved_until_utc if self.shelved(now) else None,
                "shelved_by": self.shelved_by if self.shelved(now) else None}


def raised(alarm: Alarm | None, cid: str, source: str, message: str, now: datetime) -> Alarm | None:
    """The alarm once its condition holds: new, activated again (counted), or None when it is
    active already."""
    condition(cid)
    stamp = now.isoformat(timespec="milliseconds")
    if alarm is None:
        return Alarm(cid, source, message, True, False, stamp)
    if alarm.active:
        return None
    return replace(alarm, message=message, active=True, acked=False, raised_utc=stamp, count=alarm.count + 1,
                   cleared_utc=None, acked_utc=None, acked_by=None, ack_comment=None)


def cleared(alarm: Alarm, now: datetime) -> Alarm | None:
    """The alarm once its condition no longer holds, or None when it was not active."""
    if not alarm.active:
        return None
    return replace(alarm, active=False, cleared_utc=now.isoformat(timespec="milliseconds"))


def acknowledged(alarm: Alarm, user: str, comment: str, now: datetime) -> Alarm:
    """The alarm acknowledged by ``user``; InputError when there is nothing to acknowledge."""
    if alarm.acked:
        raise InputError(f"alarm {alarm.id} ({alarm.condition} {alarm.source}) is already acknowledged"
                         + (f" by {alarm.acked_by}" if alarm.acked_by else ""))
    return replace(alarm, acked=True, acked_utc=now.isoformat(timespec="milliseconds"), acked_by=user,
                   ack_comment=comment or None)


def shelved(alarm: Alarm, user: str, duration: timedelta, now: datetime) -> Alarm:
    """The alarm shelved by ``user`` for ``duration`` (at most :data:`MAX_SHELVE`)."""
    if not timedelta(0) < duration <= MAX_SHELVE:
        raise InputError(f"shelve for more than 0 and at most {MAX_SHELVE.days} days, got {duration}")
    until = (now + duration).isoformat(timespec="milliseconds")
    return replace(alarm, shelved_until_utc=until, shelved_by=user)


def unshelved(alarm: Alarm, now: datetime) -> Alarm:
    """The alarm annunciated again; InputError when it is not shelved."""
    if not alarm.shelved(now):
        raise InputError(f"alarm {alarm.id} is not shelved")
    return replace(alarm, shelved_until_utc=None, shelved_by=None)


_PART = re.compile(r"([0-9]{1,9}(?:\.[0-9]{1,9})?)\s*([dhms])", re.ASCII)  # ASCII digits only
_UNIT_S = {"d": 86400.0, "h": 3600.0, "m": 60.0, "s": 1.0}


def parse_duration(text: str, what: str = "--for") -> timedelta:
    """``30m``, ``2h``, ``1h30m``, ``90s``, ``1d`` → timedelta; InputError naming ``what``."""
    s = text.strip().lower()
    parts = _PART.findall(s)
    if not s or not parts or _PART.sub("", s).strip():
        raise InputError(f"{what}: {text!r} is not a duration (e.g. 30m, 2h, 1h30m, 1d)")
    return timedelta(seconds=sum(float(n) * _UNIT_S[u] for n, u in parts))


def now_utc() -> datetime:
    return datetime.now(UTC)

