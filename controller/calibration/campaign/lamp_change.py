"""Changing the lamp of a night without a stray beam (docs/campaigns.md, "Lamp changes").

A standby pose keeps the beam of the lamp it was computed for off every target. Under another
lamp the same pose reflects that lamp somewhere else — possibly onto a target where another
heliostat is being measured. So before a lamp is lit, with every lamp dark:

* each heliostat of the new lamp's passes goes to its standby for that lamp beside its first
  aim point (its cycle then starts with a short, checked slew);
* every other heliostat of the night stays where it is when its beam under the new lamp
  lands as far from every target as a standby beam does (``standby_offset_m`` from the centre,
  so its spot stays out of the cameras' views) and out of every person zone, and otherwise
  goes to its standby beside the calibration target for the new lamp;
* a standby that is out of reach or would itself light a target or a person zone is replaced
  by the stow pose, which must pass the same check.

The moves are made in the dark, all heliostats at once, and waited for. Only then may the lamp
be lit. A heliostat that does not answer, cannot be moved or ends on an unsafe pose stops the
change with :class:`LampChangeError` naming it: its beam under the new lamp is not known to be
off the targets, so the lamp must stay dark.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from controller.calibration.campaign.field import Field
from controller.calibration.campaign.stay_check import certainly_safe
from controller.calibration.cycle.beam_safety import UnsafePath
from controller.calibration.cycle.park import park
from controller.calibration.cycle.pointing import GeometryPointing
from controller.calibration.cycle.warm import warm_aims
from controller.calibration.records import ModelRecord
from controller.config import PlantConfig
from controller.devices.drive import Drive, DriveError
from controller.devices.plant_time import PlantTime
from controller.errors import HeliocalError, LimitError
from controller.geometry.target_frame import TargetFrame


class LampChangeError(HeliocalError):
    """A heliostat could not be made safe for the next lamp: the lamp must not be lit."""


@dataclass(frozen=True)
class LampChange:
    """What was done in the dark before ``lamp`` was lit: the heliostats checked, those moved to
    their standby for it and those stowed."""

    lamp: str
    checked: int
    parked: tuple[str, ...]
    stowed: tuple[str, ...]

    def to_json(self) -> dict:
        return {"lamp": self.lamp, "checked": self.checked, "parked": list(self.parked),
                "stowed": list(self.stowed)}


@dataclass(frozen=True)
class Standby:
    """Where a heliostat waits under the new lamp: beside ``aim_enu`` (m ENU) on ``target``
    (None: the calibration target and its centre); ``required``: it must go there (it is in
    the lamp's passes), else only when its present pose is unsafe."""

    target: str | None = None
    aim_enu: tuple[float, float, float] | None = None
    required: bool = False


class LampChanger:
    """Makes the heliostats of a night safe for a new lamp in the dark (module docstring), on
    ``plant`` (:class:`controller.calibration.campaign.field.Field`: its drives, latest models, lamps and
    time). ``lights_out()``: switches every lamp off — default the field's lamps (a lamp panel,
    confirmed dark); a field without a panel must hand in how its operator is asked."""

    def __init__(self, plant: Field, *, move_timeout_s: float = 120.0,
                 lights_out: Callable[[], None] | None = None) -> None:
        self.cfg = plant.cfg
        self.field = plant
        self.time = plant.time
        self.lights_out = lights_out or plant.lights_out
        self.move_timeout_s = move_timeout_s
        self._frames: dict[str, TargetFrame] = {}

    def pointing(self, hid: str, lamp: str, where: Standby, current: tuple[int, int],
                 model: ModelRecord | None = None) -> GeometryPointing:
        cfg = self.cfg.for_target(where.target) if where.target else self.cfg
        cal, frame = cfg.calibration, self._frame(cfg)
        return GeometryPointing(cfg.heliostat(hid), cfg.target(), cfg.light_source(lamp), frame,
                                cal.standby_offset_m, current, cal.model, where.aim_enu,
                                others=self.cfg.targets, zones=self.cfg.person_zones, model=model)

    def _frame(self, cfg: PlantConfig) -> TargetFrame:
        """The view of ``cfg``'s calibration target, one per target: a lamp change asks for it per
        heliostat."""
        key, cam = cfg.target().id, cfg.camera
        if key not in self._frames:
            self._frames[key] = TargetFrame.from_config(cfg.target(), (cam.height_px, cam.width_px))
        return self._frames[key]

    def __call__(self, lamp: str, standby: dict[str, Standby]) -> LampChange:
        """Switch the lamps off and leave every heliostat of ``standby`` on a pose whose beam
        under ``lamp`` is off every target (module docstring); LampChangeError otherwise."""
        self.lights_out()
        # A heliostat stays put only when its beam lands as far from every target as its standby
        # beam would (GeometryPointing.stay_margin_m; its standby offset grows with its spot):
        # closer, its spot's tails would fall into a camera's view and spoil others'
        # measurements, though it is off the target.
        moving: dict[str, tuple[Drive, GeometryPointing, tuple[int, int] | None]] = {}
        stowed: list[str] = []
        # Checking and commanding the field is the controller's own work, costing the plant the
        # time it takes (a simulated plant's clock at 1x); the moves happen meanwhile.
        with self.time.computing():
            models = self.field.models(list(standby))  # one query for the night's heliostats
            drives, poses = {}, {}
            for hid in standby:
                drives[hid] = self._ask(hid, lamp, lambda h=hid: self.field.drive(h))
                st = self._ask(hid, lamp, drives[hid].status)
                poses[hid] = (st.az_steps, st.el_steps)
            # The whole field's beams under the new lamp at once; only the heliostats that are
            # not certainly clear are checked one by one below, exactly as their cycle would.
            clear = certainly_safe(self.cfg, lamp, {h: poses[h] for h, w in standby.items() if _default(w)},
                                   models, self._frame(self.cfg))
            check = {hid: self.pointing(hid, lamp, where, poses[hid], models[hid])
                     for hid, where in standby.items() if hid not in clear}
            warm_aims(check.values())  # their standby offsets and steps, in batches
            for hid, p in check.items():
                where, drive, model = standby[hid], drives[hid], models[hid]
                if not where.required and _safe(p, *poses[hid], p.stay_margin_m()):
                    continue
                pose = _safe_standby(p, model)
                try:
                    if pose is None:
                        raise LimitError("no safe standby for it")
                    drive.move_abs(*pose)
                    moving[hid] = (drive, p, pose)
                except (LimitError, DriveError):
                    self._ask(hid, lamp, drive.stow)
                    moving[hid] = (drive, p, None)
                    stowed.append(hid)
        for hid, (drive, p, pose) in moving.items():
            st = self._ask(hid, lamp, lambda d=drive, e=pose: d.wait_in_position(
                self.move_timeout_s, self.time, expect=e))
            with self.time.computing():
                safe = _safe(p, st.az_steps, st.el_steps)
            if not safe:
                raise LampChangeError(f"lamp {lamp} not lit: {hid} at ({st.az_steps}, {st.el_steps}) "
                                      f"would reflect it onto a target")
        return LampChange(lamp, len(standby), tuple(h for h in moving if h not in stowed), tuple(stowed))

    @staticmethod
    def _ask(hid: str, lamp: str, call):
        try:
            return call()
        except DriveError as exc:
            raise LampChangeError(f"lamp {lamp} not lit: {hid} could not be made safe for it ({exc})") \
                from exc


def _default(where: Standby) -> bool:
    """Whether ``where`` is the default standby (beside the calibration target's centre, only
    when unsafe): the one :func:`certainly_safe` evaluates for the whole field."""
    return not where.required and where.target is None and where.aim_enu is None


def _safe_standby(p: GeometryPointing, model: ModelRecord | None) -> tuple[int, int] | None:
    """The standby steps of ``p`` under its source, or None when they are out of reach or the
    beam there would light a target or enter a person zone."""
    try:
        pose = p.standby_steps(model)
    except (LimitError, ValueError, UnsafePath):
        return None
    return pose if _safe(p, *pose) else None


def _safe(p: GeometryPointing, az_steps: float, el_steps: float, margin_m: float = 2.0) -> bool:
    """Whether the beam at this pose is off the pointing's target and every other target, each
    grown by ``margin_m``, and out of every person zone."""
    return p.off_targets(az_steps, el_steps, margin_m)


def clear_targets(pointing: dict[str, GeometryPointing], current: dict[str, tuple[int, int]],
                  drive_of: Callable[[str], Drive], model_of: Callable[[str], ModelRecord | None], *,
                  timeout_s: float, time: PlantTime) -> list[str]:
    """Before a campaign lights its source (which may already be lit): every heliostat of
    ``pointing`` whose beam under that source lands on a target at its ``current`` pose goes to
    its standby along a beam-safe path (:func:`controller.calibration.cycle.park.park`), one after
    another. Its cycle would park it too, but only when its turn in the queue comes; until then
    its beam would sit on a target. Heliostats without a ``current`` pose (unreachable) are
    left to their cycles. The ids moved; UnsafePath or DriveError end the campaign before it
    starts."""
    moved = []
    for hid, p in pointing.items():
        if hid not in current or _safe(p, *current[hid]):
            continue
        drive = drive_of(hid)
        park(drive, p, p.standby_steps(model_of(hid)),
             lambda az, el, d=drive: d.move_and_wait(az, el, timeout_s=timeout_s, time=time),
             status=_Pose(*current[hid]))
        moved.append(hid)
    return moved


@dataclass(frozen=True)
class _Pose:
    """A pose just read (a drive status's steps), to park from without reading it again."""

    az_steps: int
    el_steps: int
