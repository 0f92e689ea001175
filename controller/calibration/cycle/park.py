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

from controller.errors import HeliocalError


class _Pointing(Protocol):
    def path_to(self, start: tuple[int, int], end: tuple[int, int]) -> list[tuple[int, int]]: ...

    def off_targets(self, az_steps: float, el_steps: float, margin_m=2.0) -> bool: ...

    def view_margin_m(self): ...


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


def safe_where_it_stands(drive: Any, pointing: _Pointing) -> bool:
    """Whether ``drive`` stands still with its beam off every target's view (the pointing's
    ``view_margin_m`` beyond each target: the spot's footprint out of every camera) and out of
    every person zone. A cycle whose park failed stays there rather than stow: the firmware's
    stow sweeps the beam unchecked and may leave it in a view where other beams are measured
    (issue 42)."""
    st = drive.status()
    return not st.moving and pointing.off_targets(st.az_steps, st.el_steps, pointing.view_margin_m())


STOWED_BESIDE = "stowed beside a target"  # stay_or_stow: the stow's beam is not off every view


def stay_or_stow(drive: Any, pointing: _Pointing, timeout_s: float, time: Any) -> str:
    """After a park that failed: "stayed" when the heliostat may stay where it stands
    (:func:`safe_where_it_stands`), else the firmware's stow, waited for, and "stowed" — or
    :data:`STOWED_BESIDE` when the stowed beam is not off every view."""
    if safe_where_it_stands(drive, pointing):
        return "stayed"
    drive.stow()
    drive.wait_in_position(timeout_s, time=time)
    return "stowed" if safe_where_it_stands(drive, pointing) else STOWED_BESIDE


def leave_pose(cyc) -> tuple[int, int]:
    """Where a calibration cycle ``cyc``'s heliostat parks after its measurement: the standby
    point on the side nearest its aim (:meth:`GeometryPointing.leave_steps`, with the model
    refitted on its last measurement, which it is given), so that its beam leaves the target the
    short way and with what the measurement showed — if the slew there keeps the beam off the
    other targets and out of the person zones (``BeamSafety.path_to``); else its standby."""
    if cyc.at is None:
        return cyc.standby
    p = cyc.ctx.pointing
    last = cyc.run_rec.measurements[-1] if cyc.run_rec.measurements else None
    try:
        pose = p.leave_steps(cyc.run_rec.model or cyc.ctx.model,
                             last and ((last.az_steps, last.el_steps), last.centroid_enu))
        p.path_to(cyc.at, pose)
    except (HeliocalError, ValueError):
        return cyc.standby
    return pose
