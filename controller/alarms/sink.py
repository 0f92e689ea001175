"""What orchestration raises alarms and records audited actions through. The interface layer
hands them in on the :class:`controller.calibration.campaign.field.Field` (the record store's
:class:`controller.storage.alarms.AlarmBook` and :class:`controller.storage.audit.AuditTrail`);
a field without them raises nothing and records nothing (:data:`NO_ALARMS`, :data:`NO_AUDIT`)."""

from __future__ import annotations

from typing import Protocol


class AlarmSink(Protocol):
    """Raise and clear alarms, one per condition and source (docs/plant-integration.md)."""

    def raise_alarm(self, condition: str, source: str, message: str) -> None: ...

    def clear_alarm(self, condition: str, source: str | None = None) -> None:
        """Clear the alarm of ``condition`` on ``source`` (None: on every source)."""


class AuditSink(Protocol):
    """Record an action that moved hardware, switched a lamp, started or stopped a night, or
    changed a model — by whoever the interface layer bound the sink to."""

    def record(self, action: str, target: str = "", detail: str = "") -> None: ...


class _NoAlarms:
    def raise_alarm(self, condition: str, source: str, message: str) -> None:
        """A field without an alarm list: the error that raised it is still reported."""

    def clear_alarm(self, condition: str, source: str | None = None) -> None:
        """Nothing to clear."""


class _NoAudit:
    def record(self, action: str, target: str = "", detail: str = "") -> None:
        """A field without an audit trail (a simulation, a benchmark)."""


NO_ALARMS: AlarmSink = _NoAlarms()
NO_AUDIT: AuditSink = _NoAudit()
