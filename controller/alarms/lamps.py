"""The lamps' alarms: a lamp that does not confirm the state it was switched to raises
``lamp_not_dark`` or ``lamp_not_lit`` on its channel (the error still stops what was running)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from controller.alarms.conditions import LAMP_NOT_DARK, LAMP_NOT_LIT
from controller.alarms.sink import AlarmSink
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
