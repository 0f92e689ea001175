"""Planning of a campaign: slew-time estimates and the order of the queue."""

from __future__ import annotations

import math

from controller.calibration.beam_safety import UnsafePath
from controller.calibration.pointing import GeometryPointing
from controller.config import PlantConfig
from controller.errors import LimitError


def slew_time_s(steps: float, speed: float, accel: float) -> float:
    """Duration of a trapezoidal (or triangular) move of ``steps`` at ``speed``/``accel``, s."""
    d = abs(float(steps))
    ramp = speed * speed / accel
    return 2 * math.sqrt(d / accel) if d < ramp else d / speed + speed / accel


def order_queue(cfg: PlantConfig, ids: list[str], current: dict[str, tuple[int, int]],
                pointing: dict[str, GeometryPointing]) -> list[str]:
    """Heliostats by estimated slew time from ``current`` steps to standby, shortest first
    (ties by id, so the order is reproducible)."""
    def t(hid: str) -> float:
        h = cfg.heliostat(hid)
        p = pointing[hid]
        try:
            saz, sel = p.standby_steps(p.model)
        except (LimitError, ValueError, UnsafePath):  # no standby: put it last, its cycle will report why
            return math.inf
        az, el = current.get(hid, (saz, sel))
        ax = h.axes
        a, e = ax.azimuth, ax.elevation
        return max(slew_time_s(saz - az, a.speed_steps_per_s, a.acceleration_steps_per_s2),
                   slew_time_s(sel - el, e.speed_steps_per_s, e.acceleration_steps_per_s2))

    return sorted(ids, key=lambda h: (t(h), h))
