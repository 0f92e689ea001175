"""The one beam-safe park: from wherever the drive stands to the standby pose, through the
waypoints :meth:`controller.calibration.cycle.pointing.GeometryPointing.path_to` plans so that the
beam sweeps no target and no person zone on the way (docs/campaigns.md, "Beam safety").

The calibration cycle, commissioning, a campaign clearing its queue's beams and the lamp
change all park through it; each hands in its own move (the cycle's can be cancelled by its
state machine, commissioning's records a step).
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from typing import Any, Protocol


class _Pointing(Protocol):
    def path_to(self, start: tuple[int, int], end: tuple[int, int]) -> list[tuple[int, int]]: ...


def park(drive: Any, pointing: _Pointing, standby: tuple[int, int],
         move: Callable[[int, int], Any], status: Any = None,
         computing: Callable[[], AbstractContextManager] = nullcontext) -> Any:
    """Read the drive's pose (or take ``status``, a reading just made), then ``move(az, el)``
    through each waypoint of the beam-safe path to ``standby`` (motor steps), planned inside
    ``computing()`` (``PlantTime.computing``). Returns the last move's result (the status when
    no move was needed). UnsafePath when no safe path exists: nothing has moved then."""
    st = drive.status() if status is None else status
    out = st
    with computing():
        path = pointing.path_to((st.az_steps, st.el_steps), standby)
    for az, el in path:
        out = move(az, el)
    return out
