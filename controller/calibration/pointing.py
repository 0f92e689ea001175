"""Geometry of one heliostat for the calibration cycle: aim and standby steps, beam-safe
slews, corrections and the tracking-error fit (the cycle's ``Pointing``)."""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from datetime import datetime

import numpy as np

from controller.calibration.observations import Step
from controller.calibration.records import MeasurementRecord, ModelRecord
from controller.config import Heliostat, LampSource, ModelSettings, PersonZone, PlantConfig, Target
from controller.errors import HeliocalError, InputError, LimitError
from controller.geometry.aiming import aim_normal, source_direction
from controller.geometry.correction import correction_from_offset
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model_fit import NotIdentifiable, Sample, fit_model
from controller.geometry.target_frame import TargetFrame
from controller.geometry.tracking_model import TrackingModel, drift_sigma, model_aim, prior_sigma
from controller.geometry.vectors import vector_to_azel
from controller.geometry.zones import zone_boxes, zone_entered


class UnsafePath(HeliocalError):
    """No slew keeps the beam off the target (beam safety); nothing was sent."""


# -- geometry of one heliostat ------------------------------------------------------------------
class GeometryPointing:
    """:class:`controller.calibration.machine.Pointing` on controller.geometry.

    The aim point is the target centre; the standby point lies ``standby_offset_m`` beside it in
    the target plane, on the heliostat's own side, so the approach is a short horizontal slew.
    ``others``: the plant's other targets, which slews must never cross either (their beams
    belong to other pipelines that run at the same time). ``zones``: the plant's person zones
    (config ``person_zones``), which the beam must never enter — at standby, on a slew, on the
    approach or at the aim point.
    """

    def __init__(self, heliostat: Heliostat, target: Target, source, frame: TargetFrame,
                 standby_offset_m: float, current_steps: tuple[int, int] | None = None,
                 model_settings: ModelSettings | None = None, aim_point=None,
                 others: tuple[Target, ...] = (), zones: tuple[PersonZone, ...] = ()) -> None:
        self.model_settings = model_settings or ModelSettings()
        model_prior(self.model_settings)  # an unknown term is refused before anything moves
        self.kin = HeliostatKinematics.from_config(heliostat)
        self.heliostat_pos = np.asarray(heliostat.position_enu_m, float)
        self.target = target
        # The target centre, or a point of the aim grid on a planned night.
        self.aim_point = np.asarray(target.center_enu_m if aim_point is None else aim_point, float)
        self.source_dir = np.asarray(source_direction(source, self.heliostat_pos), float)
        self.source_pos = (tuple(float(v) for v in source.position_enu_m) if isinstance(source, LampSource)
                           else None)
        self.heliostat = heliostat
        self.frame = frame
        self.others = tuple((np.asarray(t.center_enu_m, float), TargetFrame.from_config(t, (1, 1)), t)
                            for t in others if t.id != target.id)
        self.zones, self.zone_ids = zone_boxes(zones), [z.id for z in zones]
        own = frame.side(self.heliostat_pos)
        self.standby_point = self.aim_point + standby_offset_m * own
        if current_steps is not None or self.zone_ids:
            # Park on the side the slew from the present pose reaches first (azimuth steps
            # closer to the present ones), so the beam does not pass the target on its way;
            # without a present pose, on the heliostat's own side. Never on a side whose
            # standby beam would enter a person zone.
            best = None
            for side in (own, -own):
                point = self.aim_point + standby_offset_m * side
                try:
                    az, el = self.kin.aim(self.source_dir, point)
                except (LimitError, ValueError):  # unreachable side
                    continue
                if self.beam_in_zone(az, el) is not None:
                    continue
                cost = abs(az - current_steps[0]) if current_steps is not None else float(side is not own)
                if best is None or cost < best[0]:
                    best = (cost, point)
            if best is not None:
                self.standby_point = best[1]

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

    def _steps(self, point: np.ndarray, model: ModelRecord | None) -> tuple[int, int]:
        return steps_to_aim(self.kin, model, self.source_dir, point, self.source_pos)

    def aim_steps(self, model: ModelRecord | None) -> tuple[int, int]:
        """Steps onto the aim point; UnsafePath when the beam there, or on the approach from
        standby, would enter a person zone (nothing has moved yet)."""
        aim = self._steps(self.aim_point, model)
        if self.zone_ids:
            for pose in self._sweep(self.standby_steps(model), aim):
                zone = self.beam_in_zone(*pose)
                if zone is not None:
                    raise UnsafePath(f"{self.heliostat.id}: the approach to the aim point {aim} would send "
                                     f"the beam into person zone {zone!r}")
        return aim

    def standby_steps(self, model: ModelRecord | None) -> tuple[int, int]:
        """Steps onto the standby point; UnsafePath when the beam there would enter a person zone."""
        standby = self._steps(self.standby_point, model)
        zone = self.beam_in_zone(*standby)
        if zone is not None:
            raise UnsafePath(f"{self.heliostat.id}: the standby pose {standby} would send the beam into "
                             f"person zone {zone!r}")
        return standby

    def fine_correction(self, az_steps: int, el_steps: int, offset_enu: np.ndarray) -> Step:
        c = correction_from_offset(self.kin, az_steps, el_steps, self.source_dir, None, self.target,
                                   offset_enu)
        return Step(c.daz_deg, c.del_deg, c.daz_steps, c.del_steps)

    def coarse_correction(self, az_steps: int, el_steps: int, daz_deg: float, del_deg: float) -> Step:
        alpha, eps = self.kin.angles(az_steps, el_steps)
        daz = self.kin.azimuth.steps_float(alpha + math.radians(daz_deg)) - az_steps
        dele = self.kin.elevation.steps_float(eps + math.radians(del_deg)) - el_steps
        return Step(daz_deg, del_deg, int(round(float(daz))), int(round(float(dele))))

    def fit(self, measurements: list[MeasurementRecord], prior: ModelRecord | None) -> ModelRecord | None:
        """Tracking-model fit over all measurements of this heliostat (earlier runs included),
        by identifiability: every term is regularised towards its nominal value with the
        plant's prior σ (``calibration.model``), so the data move only what they observe
        (:func:`controller.geometry.model_fit.fit_model`). ``prior`` (the last model) is kept
        when there is nothing to fit or the data identify no term."""
        return fit_measurements(self.kin, measurements, self.model_settings) or prior


def fit_measurements(kin: HeliostatKinematics, measurements: list[MeasurementRecord],
                     settings: ModelSettings) -> ModelRecord | None:
    """:class:`ModelRecord` of the MAP fit to ``measurements`` (those with a centroid), with the
    noise and prior σ of ``settings`` (:class:`controller.config.ModelSettings`); None when no
    measurement has a centroid or the data identify no term."""
    used = [m for m in measurements if m.centroid_enu is not None]
    if not used:
        return None
    stamps = [m.measured_utc for m in used]
    weights = age_weights(stamps, settings.age_halflife_days)
    epochs, days = night_epochs(stamps)
    samples = [Sample(np.asarray(m.source_dir, float), m.az_steps, m.el_steps,
                      np.asarray(m.centroid_enu, float), float(w),
                      None if m.source_pos_enu is None else np.asarray(m.source_pos_enu, float), int(e))
               for m, w, e in zip(used, weights, epochs, strict=True)]
    drift = drift_sigma(settings.prior_sigma)
    # A random walk: the references of a night d days before the newest are off by σ √d.
    epoch_sigma = {e: drift * math.sqrt(d) for e, d in days.items() if e > 0} if drift > 0 else None
    try:
        fit = fit_model(kin, samples, noise_mrad=settings.noise_mrad, prior_sigma=model_prior(settings),
                        epoch_sigma=epoch_sigma)
    except NotIdentifiable:
        return None
    detail = {"covariance_si": fit.covariance.tolist(), "identified": fit.identified_terms(),
              "noise_scale": fit.noise_scale, "converged": fit.converged}
    return ModelRecord(fit.model.to_dict(), fit.sigma_dict(), float(fit.residual_mrad_rms), len(samples),
                       detail)


def model_prior(settings: ModelSettings, source: str = "") -> np.ndarray:
    """Prior 1-σ (SI) of every tracking-model term from ``calibration.model``; InputError
    naming ``source`` (the config file) and an unknown term key."""
    return prior_sigma(settings.prior_sigma, f"{source}: calibration.model.prior_sigma" if source
                       else "calibration.model.prior_sigma")


NIGHT_GAP_S = 6 * 3600.0  # measurements further apart than this were taken on different nights


def night_epochs(stamps: list[str]) -> tuple[list[int], dict[int, float]]:
    """The night of each measurement (ISO 8601 UTC ``stamps``), counted back from the newest
    (0), nights being runs of measurements without a gap of :data:`NIGHT_GAP_S`; and per night
    its distance in days from the newest (at least 1 for an earlier night). An unreadable
    stamp belongs to the newest night."""
    t = [_timestamp(s) for s in stamps]
    known = sorted({v for v in t if v is not None})
    if not known:
        return [0] * len(stamps), {0: 0.0}
    starts = [known[0]] + [b for a, b in zip(known, known[1:], strict=False) if b - a > NIGHT_GAP_S]
    last = len(starts) - 1
    days = {last - i: 0.0 if i == last else max(1.0, round((starts[-1] - st) / 86400.0))
            for i, st in enumerate(starts)}
    epoch = [0 if v is None else last - (bisect.bisect_right(starts, v) - 1) for v in t]
    return epoch, days


def _timestamp(s: str) -> float | None:
    try:
        return datetime.fromisoformat(s.replace("Z", "+00:00")).timestamp()
    except (AttributeError, ValueError):
        return None


def age_weights(stamps: list[str], halflife_days: float) -> np.ndarray:
    """Fit weight of each measurement, w = 2^(−age / half-life), its age counted in days back
    from the newest of ``stamps`` (ISO 8601 UTC): the heliostat drifts, so old measurements
    tell less about it now. An unreadable stamp weighs 1."""
    t = [_timestamp(s) for s in stamps]
    known = [v for v in t if v is not None]
    if not known:
        return np.ones(len(stamps))
    newest = max(known)
    return np.array([1.0 if v is None else 0.5 ** ((newest - v) / 86400.0 / halflife_days) for v in t])


def steps_to_aim(kin: HeliostatKinematics, model: ModelRecord | None, source_dir: np.ndarray,
                 point: np.ndarray, lamp_position=None) -> tuple[int, int]:
    """Motor steps that reflect light from ``source_dir`` (unit ENU, towards the source) onto
    ``point`` (m ENU): with the fitted tracking-error ``model`` (the bisector normal made the
    *actual* normal, :func:`controller.geometry.tracking_model.model_aim`), or the nominal
    kinematics without one. For a lamp at ``lamp_position`` (m ENU) the model takes its direction
    from the model's mirror centre. LimitError when the pose is out of reach."""
    if model is None:
        return kin.aim(source_dir, point)
    return model_aim(kin, TrackingModel.from_dict(model.params), source_dir, point,
                     lamp_position=lamp_position)


@dataclass(frozen=True)
class NominalAim:
    """Aim of one heliostat with the nominal kinematics (no error model): light-source
    direction and mirror normal (ENU unit vectors), normal azimuth/elevation (degrees,
    azimuth clockwise from north) and motor steps."""

    heliostat_id: str
    source_dir: np.ndarray
    normal: np.ndarray
    az_deg: float
    el_deg: float
    az_steps: int
    el_steps: int


def nominal_aims(cfg: PlantConfig, ids: list[str]) -> list[NominalAim]:
    """Nominal aim of each heliostat at the calibration target's centre under the
    calibration light source (a lamp)."""
    src = cfg.light_source()
    if not isinstance(src, LampSource):
        raise InputError("calibration.light_source must be a lamp for a nightly aim")
    target = np.asarray(cfg.target().center_enu_m, float)
    out = []
    for hid in ids:
        h = cfg.heliostat(hid)
        pos = np.asarray(h.position_enu_m, float)
        s = source_direction(src, pos)
        normal = aim_normal(s, pos, target)
        az, el = vector_to_azel(normal)
        a, e = HeliostatKinematics.from_config(h).steps_for_normal(normal)
        out.append(NominalAim(hid, s, normal, float(az), float(el), int(a), int(e)))
    return out
