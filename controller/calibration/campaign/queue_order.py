"""Planning of a campaign: slew-time estimates and the order of the queue."""

from __future__ import annotations

import math

from controller.calibration.cycle.beam_safety import UnsafePath
from controller.calibration.cycle.pointing import GeometryPointing
from controller.config import PlantConfig
from controller.errors import LimitError


def slew_time_s(steps: float, speed: float, accel: float) -> float:
    """Duration of a trapezoidal (or triangular) move of ``steps`` at ``speed``/``accel``, s."""
    d = abs(float(steps))
    ramp = speed * speed / accel
    return 2 * math.sqrt(d / accel) if d < ramp else d / speed + speed / accel


def _slew_s(cfg: PlantConfig, hid: str, start: tuple[int, int], end: tuple[int, int]) -> float:
    """The slower axis's :func:`slew_time_s` from ``start`` to ``end`` (motor steps), s."""
    a, e = cfg.heliostat(hid).axes.azimuth, cfg.heliostat(hid).axes.elevation
    return max(slew_time_s(end[0] - start[0], a.speed_steps_per_s, a.acceleration_steps_per_s2),
               slew_time_s(end[1] - start[1], e.speed_steps_per_s, e.acceleration_steps_per_s2))


def order_queue(cfg: PlantConfig, ids: list[str], current: dict[str, tuple[int, int]],
                pointing: dict[str, GeometryPointing], beams: int = 1, last: tuple[str, ...] = (),
                tiers: dict[str, int] | None = None) -> list[str]:
    """Heliostats by estimated slew time from ``current`` steps to standby, shortest first
    (ties by id, so the order is reproducible).

    With ``beams`` K > 1 the first K (the first round, whose beams go onto the target together)
    stay so; the others follow by their slew between standby and aim point, longest first. A
    round waits for its slowest beam to arrive and to leave, so heliostats of like slews share a
    round, and the last round — often one beam, alone on the target — is the quickest. ``last``
    (K > 1): queued last even so, the heliostats whose spot had to be measured again alone
    earlier (a large or split spot): a pass's last round is often one beam, measured alone
    anyway. ``tiers`` (K > 1; id → slot tier, −1 alone,
    :func:`controller.calibration.beams.slots.pass_layout`): the tiers in turn, in that order
    within each, the heliostats measured alone after them all."""
    def steps(hid: str, of) -> tuple[int, int] | None:  # None: out of reach, its cycle will report why
        try:
            return of(pointing[hid].model)
        except (LimitError, ValueError, UnsafePath):
            return None

    standbys = {hid: steps(hid, pointing[hid].standby_steps) for hid in ids}

    def standby(hid: str) -> float:  # no standby: last
        s = standbys[hid]
        return math.inf if s is None else _slew_s(cfg, hid, current.get(hid, s), s)

    def approach(hid: str) -> float:
        s, a = standbys[hid], steps(hid, pointing[hid].aim_steps)
        return -math.inf if s is None or a is None else _slew_s(cfg, hid, s, a)

    queue = sorted(ids, key=lambda h: (standby(h), h))
    if beams > 1:
        queue[beams:] = sorted(queue[beams:], key=lambda h: (-approach(h), h))
        later = set(last)  # hundreds, late in a night: a set, not the tuple, for each of a pass's heliostats
        queue = [h for h in queue if h not in later] + [h for h in queue if h in later]
        if tiers:
            after = max(tiers.values()) + 1
            queue.sort(key=lambda h: after if tiers.get(h, -1) < 0 else tiers[h])  # stable
    return queue
