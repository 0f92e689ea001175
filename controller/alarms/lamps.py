"""The lamps' alarms: a lamp that does not confirm the state it was switched to raises
``lamp_not_dark`` or ``lamp_not_lit`` on its channel (the error still stops what was running);
the lights out at the end of a night or campaign raises ``lamp_not_dark`` for each lamp it left
not confirmed dark, and clears it once every lamp is (:func:`lights_out_alarms`)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from controller.alarms.conditions import LAMP_NOT_DARK, LAMP_NOT_LIT
from controller.alarms.sink import AlarmSink, AuditSink
from controller.devices.lamp_panel import LampNotConfirmed


@contextmanager
def lamp_alarms(alarms: AlarmSink) -> Iterator[None]:
    """Raise the alarm of every channel a :class:`LampNotConfirmed` inside names, and re-raise."""
    try:
        yield
    except LampNotConfirmed as exc:
        cid, state = (LAMP_NOT_LIT, "lit") if exc.on else (LAMP_NOT_DARK, "dark")
        for channel in exc.channels:
            alarms.raise_alarm(cid, channel, f"lamp {channel} did not confirm {state}: {exc}")
        raise


def lights_out_alarms(alarms: AlarmSink, audit: AuditSink, session: str, ends) -> None:
    """After the lights out at the end of ``session``: ``ends`` (each lamp's
    :class:`controller.calibration.campaign.field.LampEnd`) audited, ``lamp_not_dark`` raised for each
    lamp still lit or whose panel did not answer, cleared on every channel when all are dark."""
    bad = [e for e in ends if e.state in ("lit", "no_answer")]
    for e in bad:
        alarms.raise_alarm(LAMP_NOT_DARK, e.channel, f"lamp {e.channel} not confirmed dark at the end of "
                           f"{session}: {e.detail}")
    if ends and all(e.state == "dark" for e in ends):
        alarms.clear_alarm(LAMP_NOT_DARK)
    states = ", ".join(f"{e.channel} {e.state}" for e in ends) or "no lamp"
    audit.record("lamps.off", "all", f"end of {session}: {states}")
