"""Beam safety of one heliostat: where its nominal reflected central ray lands at a pose
(on its target, on another target, into a person zone) and slews that keep it off them
(docs/campaigns.md, "Beam safety"). Every standby pose, slew, approach and lamp change is
checked here before anything moves."""

from __future__ import annotations

import numpy as np

from controller.config import Heliostat, PersonZone, Target
from controller.errors import HeliocalError
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.target_frame import TargetFrame
from controller.geometry.zones import zone_boxes, zone_entered


class UnsafePath(HeliocalError):
    """No slew keeps the beam off the target (beam safety); nothing was sent."""


class BeamSafety:
    """The beam-safety geometry of ``heliostat`` under a source in direction ``source_dir``
    (unit ENU, towards the source) with its ``target`` (its ``frame``); ``others``: the plant's
    other targets, which slews must never cross either (their beams belong to other pipelines
    that run at the same time); ``zones``: the person zones the beam must never enter."""

    def __init__(self, heliostat: Heliostat, source_dir: np.ndarray, target: Target, frame: TargetFrame,
                 others: tuple[Target, ...] = (), zones: tuple[PersonZone, ...] = ()) -> None:
        self.heliostat = heliostat
        self.kin = HeliostatKinematics.from_config(heliostat)
        self.source_dir = source_dir
        self.target = target
        self.frame = frame
        self.others = tuple((np.asarray(t.center_enu_m, float), TargetFrame.from_config(t, (1, 1)), t)
                            for t in others if t.id != target.id)
        self.zones, self.zone_ids = zone_boxes(zones), [z.id for z in zones]

    def beam_on_target(self, az_steps: float, el_steps: float, margin_m: float = 2.0) -> bool:
        """Whether the nominal reflected central ray lands on the target grown by ``margin_m``
        (spot radius plus model error)."""
        return self._lands_on(az_steps, el_steps, np.asarray(self.target.center_enu_m, float), self.frame,
                              self.target, margin_m)

    def beam_on_other_target(self, az_steps: float, el_steps: float, margin_m: float = 2.0) -> bool:
        """Whether the nominal reflected central ray lands on one of the ``others`` targets
        grown by ``margin_m``."""
        return any(self._lands_on(az_steps, el_steps, c, f, t, margin_m) for c, f, t in self.others)

    def beam_in_zone(self, az_steps: float, el_steps: float) -> str | None:
        """The id of the person zone the nominal reflected central ray enters at this pose, or
        None; a beam that lands on the target ends there."""
        if not self.zone_ids:
            return None
        origin = self.kin.mirror_center(az_steps, el_steps)
        beam = self.kin.beam(az_steps, el_steps, self.source_dir)
        stop = np.inf
        if self._lands_on(az_steps, el_steps, self.frame.center, self.frame, self.target, 0.0):
            stop = float(self.frame.normal @ (self.frame.center - origin)) / float(self.frame.normal @ beam)
        k = zone_entered(origin, beam, self.zones, stop)
        return None if k is None else self.zone_ids[k]

    def _sweep(self, a: tuple[float, float], b: tuple[float, float], samples: int = 120):
        """Poses (az, el steps) along a slew from ``a`` to ``b``, each axis moving at its
        configured speed (acceleration ignored)."""
        ax = self.heliostat.axes
        speed = np.array([ax.azimuth.speed_steps_per_s, ax.elevation.speed_steps_per_s])
        a_, b_ = np.asarray(a, float), np.asarray(b, float)
        dur = np.abs(b_ - a_) / speed
        total = float(dur.max())
        for t in np.linspace(0.0, total, samples if total > 0 else 1):
            frac = np.where(dur > 0, np.minimum(1.0, t / np.where(dur > 0, dur, 1.0)), 1.0)
            yield a_ + frac * (b_ - a_)

    def _lands_on(self, az_steps: float, el_steps: float, center: np.ndarray, frame: TargetFrame,
                  target: Target, margin_m: float) -> bool:
        try:
            hit = self.kin.spot(az_steps, el_steps, self.source_dir, center, frame.normal)
        except (ValueError, FloatingPointError):
            return False  # the beam points away from the target plane
        d = hit - center
        return (abs(float(d @ frame.u)) <= target.width_m / 2 + margin_m
                and abs(float(d @ frame.v)) <= target.height_m / 2 + margin_m)

    def path_to(self, start: tuple[int, int], end: tuple[int, int]) -> list[tuple[int, int]]:
        """Waypoints from ``start`` to ``end`` (a point off the target) along which the beam
        never crosses the target nor any of the ``others``: both axes together, else elevation
        first, else azimuth first.
        The motion model moves each axis at its configured speed (acceleration ignored).
        Nor does it enter a person zone (a beam that starts in one may leave it).
        Raises :class:`UnsafePath` when no such path exists."""

        def clear(plan: list[tuple[int, int]]) -> bool:
            # A beam that starts on a target may leave it; once off it must never enter one.
            inside = self.beam_on_target(*start)
            inside_other = self.beam_on_other_target(*start)
            inside_zone = self.beam_in_zone(*start) is not None
            for a, b in zip([start] + plan[:-1], plan, strict=True):
                for pose in self._sweep(a, b):
                    on, on_other = self.beam_on_target(*pose), self.beam_on_other_target(*pose)
                    in_zone = self.beam_in_zone(*pose) is not None
                    if (on and not inside) or (on_other and not inside_other) \
                            or (in_zone and not inside_zone):
                        return False
                    inside, inside_other = inside and on, inside_other and on_other
                    inside_zone = inside_zone and in_zone
            return True

        plans = ([end], [(start[0], end[1]), end], [(end[0], start[1]), end])
        for plan in plans:
            if clear(plan):
                return [p for p in plan if p != start]
        raise UnsafePath(f"{self.heliostat.id}: no slew from {start} to standby {end} keeps the beam "
                         "off the targets")
