"""Lights out at every end of a night or a campaign (docs/lamps.md, "Lights out").

Whatever ends a night or a calibration campaign — it finished, it was partial, it aborted, the
operator interrupted it, an exception stopped it — :func:`lights_out_at_end` switches every
channel of the field's lamp panel off (fiducials too), waits for each to confirm dark and reads
every channel back. Each channel's end state goes into the store (``lamp_states``, through
:class:`LampBook`), a lamp not confirmed dark is told to every observer
(:meth:`controller.calibration.campaign.observers.CampaignObserver.lamp_not_dark`) and raised as the
alarm ``lamp_not_dark`` on the field's alarm list (:func:`controller.alarms.lamps.lights_out_alarms`),
then stops the command with one line naming it (:class:`LampNotDark`, exit 1).
Nothing about it is silent.

A field without a lamp panel cannot confirm anything: its operator is asked to switch the
lamps off, and the lamps the session lit are recorded ``operator``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Protocol

from controller.alarms.lamps import lights_out_alarms
from controller.calibration.campaign.field import Field, LampEnd
from controller.calibration.campaign.observers import CampaignObserver
from controller.devices.lamp_panel import LampError


class LampNotDark(LampError):
    """A lamp was not confirmed dark at the end of a night or campaign (recorded, told)."""


class LampBook(Protocol):
    """Where the end states go (:class:`controller.storage.nights.NightBook`)."""

    def record_lamp_states(self, session: str, ended: str, lamps: list[LampEnd]) -> None: ...


def lights_out_at_end(plant: Field, book: LampBook, session: str, ended: str, observer: CampaignObserver, *,
                      lit: Iterable[str] = (), ask_operator: Callable[[], None] | None = None
                      ) -> list[LampEnd]:
    """Every lamp off and confirmed dark at the end of ``session`` (a night or campaign name)
    that ended ``ended`` (module docstring); returns each channel's end state, recorded, and
    tells the observer of each lamp not confirmed dark (:func:`require_dark` then stops).
    ``lit``: the lamps the session lit (recorded ``operator`` on a field without a panel, whose
    operator ``ask_operator`` asks)."""
    if plant.lamps is None:
        if ask_operator is not None:
            ask_operator()
        ends = [LampEnd(lamp, "operator", detail="no lamp panel: the operator was asked to switch it off")
                for lamp in dict.fromkeys(lit)]
    else:
        ends = _panel_ends(plant)
    book.record_lamp_states(session, ended, ends)
    lights_out_alarms(plant.alarms, plant.audit, session, ends)
    bad = [e for e in ends if e.state in ("lit", "no_answer")]
    for e in bad:
        observer.lamp_not_dark(session, e)
    return ends


def not_dark_message(session: str, ends: list[LampEnd]) -> str | None:
    """One line naming the lamps of ``ends`` not confirmed dark, or None when none is."""
    bad = [e for e in ends if e.state in ("lit", "no_answer")]
    if not bad:
        return None
    names = ", ".join(e.channel for e in bad)
    return f"lamp{'s' * (len(bad) > 1)} {names} not confirmed dark at the end of {session}: {bad[0].detail}"


def require_dark(session: str, ends: list[LampEnd], after: BaseException | None = None) -> None:
    """:class:`LampNotDark` naming the lamps of ``ends`` not confirmed dark; ``after``: the
    exception that ended the session (named in the line, chained)."""
    line = not_dark_message(session, ends)
    if line is None:
        return
    if after is not None:
        why = "interrupted by the operator" if isinstance(after, KeyboardInterrupt) else \
            f"{type(after).__name__}: {after}"
        raise LampNotDark(f"{line} (it had stopped: {why})") from after
    raise LampNotDark(line)


def _panel_ends(plant: Field) -> list[LampEnd]:
    """Switch every channel off, wait for dark, and read every channel back."""
    lamps = plant.lamps
    problem: Exception | None = None
    try:
        lamps.lights_out()
    except Exception as exc:  # whatever failed, every channel is still read and recorded
        problem = exc
    try:
        states = lamps.states()
    except Exception as exc:  # the panel cannot tell: every channel is recorded so
        why = f"{problem or exc}"
        return [LampEnd(c, "no_answer", detail=why) for c in lamps.channels]
    stuck = f"still confirmed lit {lamps.timeout_s:g} s after it was switched off"
    return [LampEnd(s.channel, "lit" if s.lit else "dark", s.commanded, stuck if s.lit else None)
            for s in states]
