"""Geometry of one heliostat for the calibration cycle (the cycle's ``Pointing``): where it
aims — the aim point and the standby point beside it, with its fitted model — and the
corrections it moves by. The beam-safety geometry it checks every pose and slew with is
:mod:`controller.calibration.cycle.beam_safety`; the model update after each run is
:mod:`controller.calibration.cycle.model_update`."""

from __future__ import annotations

import math

import numpy as np

from controller.calibration.cycle.beam_safety import BeamSafety, UnsafePath
from controller.calibration.cycle.model_update import fit_measurements, model_prior, unexplained_sigma_m
from controller.calibration.cycle.observations import Step
from controller.calibration.cycle.solved import Solved, source_key
from controller.calibration.records import MeasurementRecord, ModelRecord
from controller.config import BeamSearch, Heliostat, LampSource, ModelSettings, PersonZone, Target
from controller.errors import LimitError
from controller.geometry.aiming import source_direction
from controller.geometry.correction import correction_from_offset
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model.tracking import TERMS, TrackingModel, model_aim
from controller.geometry.pose_batch import KinStack
from controller.geometry.search_pattern import search_steps, spiral_offsets
from controller.geometry.spot import SIGMAS, MirrorOptics, park_clearances_m, predict_spots
from controller.geometry.target_frame import TargetFrame

PARK_MARGIN_M = 0.5  # a parked spot's 3σ footprint ends at least this far outside the camera's view
LEAVE_MIN_M = 0.01  # m: a leave point moves out by more only (less is noise; a moved point is solved anew)
# GeometryPointing._steps: (heliostat config, model terms, point, source) -> steps (a few per heliostat, lamp)
AIMS_KEPT = 200_000
_AIMS = Solved(AIMS_KEPT)
# GeometryPointing.park_clearance_m: (heliostat, settings, model terms, source, view) -> m.
_CLEARANCES = Solved(AIMS_KEPT)
_SPOTS = Solved(AIMS_KEPT)  # GeometryPointing.path_margin_m: the same key -> (u, v) m
DEFAULT_SETTINGS = ModelSettings()  # one object: the clearances' key names the settings by id


# -- geometry of one heliostat ------------------------------------------------------------------
class GeometryPointing(BeamSafety):
    """:class:`controller.calibration.cycle.machine.Pointing` on controller.geometry. The aim point is the
    target centre (or given); the standby point lies beside it in the target plane (:meth:`side_points`),
    a short horizontal slew away: ``standby_offset_m`` from the aim at least, and far enough from the centre
    that the parked spot, at 3σ of its size and of its position (``model``'s covariance), stays out of the
    camera's view (:meth:`park_clearance_m`). ``others``: the plant's other targets, which slews must never
    cross either (other pipelines' beams); ``zones``: the person zones (config ``person_zones``) the beam
    must never enter. ``search``: the beam search (``calibration.search``): a heliostat without a model is
    as uncertain as its ``normal_sigma_mrad`` says (it parks farther, and its search covers that,
    :meth:`search_pattern`) until ``field_misses`` (:class:`controller.calibration.cycle.search.FieldMisses`,
    shared by a campaign's heliostats) knows better."""

    def __init__(self, heliostat: Heliostat, target: Target, source, frame: TargetFrame,
                 standby_offset_m: float, current_steps: tuple[int, int] | None = None,
                 model_settings: ModelSettings | None = None, aim_point=None,
                 others: tuple[Target, ...] = (), zones: tuple[PersonZone, ...] = (),
                 model: ModelRecord | None = None, search: BeamSearch | None = None,
                 field_misses=None) -> None:
        self.search = search if search is not None and search.max_looks > 0 else None
        self.field_misses = field_misses
        self.search_step_m = (frame.width_m, frame.height_m)  # the pattern's steps (search_pattern)
        self.source = source
        self.model_settings = model_settings or DEFAULT_SETTINGS
        model_prior(self.model_settings)  # an unknown term is refused before anything moves
        self.model = model  # the model the standby and the beam-safety checks were computed with
        pos = np.asarray(heliostat.position_enu_m, float)
        self.source_pos = (tuple(float(v) for v in source.position_enu_m) if isinstance(source, LampSource)
                           else None)
        super().__init__(heliostat, np.asarray(source_direction(source, pos), float), target, frame, others,
                         zones, model and TrackingModel.from_dict(model.params), self.source_pos)
        self.heliostat_pos = pos
        # The target centre, or a point of the aim grid on a planned night.
        self.aim_point = np.asarray(target.center_enu_m if aim_point is None else aim_point, float)
        self._least_offset_m, self._offset_m = standby_offset_m, None
        self._current, self._standby_point = current_steps, None

    @property
    def standby_offset_m(self) -> float:
        """How far beside the aim point (m) the standby point on the far side of the centre lies
        (both sides for an aim at the centre): parked there, the spot must stay out of the
        camera's view — at least the configured offset, more for a large or uncertain spot
        (:meth:`park_clearance_m`, computed when first asked for; many heliostats at once:
        :mod:`controller.calibration.cycle.warm`)."""
        if self._offset_m is None:
            across = abs(float((self.aim_point - self.frame.center) @ self.frame.u))
            clearance = self.park_clearance_m(self.source, self.model)
            self._offset_m = max(self._least_offset_m, clearance + across)
        return self._offset_m

    def stay_margin_m(self) -> float:
        """How far (m) off every target the beam of a heliostat that stays where it is must land
        (a lamp change, :meth:`may_wait_at`): as far as its standby beam, its standby offset less
        half the largest target, at least 2 m — closer, its spot's tails would fall into a view."""
        half = max(max(t.width_m, t.height_m) for t in (self.target, *(o[2] for o in self.others))) / 2
        return max(2.0, self.standby_offset_m - half)

    @property
    def standby_point(self) -> np.ndarray:
        """The standby point (m ENU), chosen when first asked for (a lamp change may need none)."""
        if self._standby_point is None:
            self._standby_point = self._choose_standby()
        return self._standby_point

    def side_points(self) -> tuple[np.ndarray, np.ndarray]:
        """The standby points (m ENU) on the heliostat's own side of the target and on the other:
        along the view's width, u = s · max(c, s · a + d) from the centre on side s = ±1, with c
        the park clearance (:meth:`park_clearance_m`), a the aim point's u and d the configured
        offset — a slot's beam parks beside its own side of the view, not the aim's offset
        beyond it (before 2026-11-29: c + |a| from the aim on both sides)."""
        f, a = self.frame, float((self.aim_point - self.frame.center) @ self.frame.u)
        c = self.standby_offset_m - abs(a)  # the clearance, or less where d sets the offset
        if not np.isfinite(c):  # no park beside this view in reach: _steps refuses these points
            return np.full(3, np.inf), np.full(3, np.inf)
        own = float(f.side(self.heliostat_pos) @ f.u)
        return tuple(self.aim_point + (s * max(c, s * a + self._least_offset_m) - a) * f.u
                     for s in (own, -own))

    def _choose_standby(self) -> np.ndarray:
        current_steps, model, frame = self._current, self.model, self.frame
        own = frame.side(self.heliostat_pos)
        points = self.side_points()
        chosen = points[0]
        if current_steps is not None or self.zone_ids:
            # Park on the side where the beam is now (its ray beside the target: what the slew's
            # beam-safety check traces), else the side the slew from the present pose
            # reaches first (azimuth steps closer to the present ones), so the beam does not
            # pass the target on its way; without a present pose, on the heliostat's own side.
            # Never on a side whose standby beam would enter a person zone.
            now = self._beam_side(current_steps) if current_steps is not None else 0.0
            best = None
            for side, point in zip((own, -own), points, strict=True):
                cost = float(np.sign(float(side @ frame.u)) != now) if now else None
                if cost is not None and best is not None and cost >= best[0]:
                    continue  # no better than the side found: its steps are not needed
                try:  # the steps the model will take there: far from nominal, a side's may differ
                    az, el = self._steps(point, model) if model else self.kin.aim(self.source_dir, point)
                except (LimitError, ValueError):  # unreachable side
                    continue
                if self.beam_in_zone(az, el) is not None:
                    continue
                if cost is None:
                    cost = abs(az - current_steps[0]) if current_steps is not None else float(side is not own)
                if best is None or cost < best[0]:
                    best = (cost, point)
            if best is not None:
                chosen = best[1]
        return chosen

    def _beam_side(self, steps: tuple[int, int]) -> float:
        """+1 or −1: the side (along the view's u axis) of the target where the ray at ``steps``
        lands beside it; 0 when it lands on it (grown by its margin) or misses its plane."""
        u = float(self.plane_uv([steps])[0, 0])  # NaN (no hit): 0
        return float(np.sign(u)) if abs(u) > self.target.width_m / 2 + 2.0 else 0.0

    def park_clearance_m(self, source, model: ModelRecord | None) -> float:
        """The least distance (m) from the target centre, along the view's width, at which this
        heliostat's spot stays :data:`PARK_MARGIN_M` outside the camera's view at 3σ of its size and
        position (:meth:`spot_sigmas_m`, at least its model's unexplained σ: :func:`unexplained_sigma_m`)
        where it is parked beside the view on either side (:func:`controller.geometry.spot.park_clearance_m`):
        one per heliostat, model, source and view, whatever the aim point."""
        key = self._clearance_key(source, model)
        return _CLEARANCES.get(key, (self.heliostat, self.model_settings),
                               lambda: float(clearances([(self, source, model)])[0]))

    def _clearance_key(self, source, model: ModelRecord | None) -> tuple:
        f, terms = self.frame, None if model is None else (tuple(model.params.items()), model.residual_mrad)
        return (id(self.heliostat), id(self.model_settings), terms, source_key(source), f.center.tobytes(),
                f.u.tobytes(), f.width_m, self.first_light_sigma_m() if model is None else 0.0)

    def spot_sigmas_m(self, source, model: ModelRecord | None) -> tuple[float, float] | None:
        """(1-σ size, 1-σ of the position) of the spot at the aim point, m: the position's from
        the model's covariance (the prior without a model; at least the measured normal's noise
        doubled, spot Eq. 3) — for a heliostat without a model under a beam search at least its
        first-light σ (:meth:`first_light_sigma_m`). None when the aim point is out of reach."""
        try:
            steps = np.array([self._steps(self.aim_point, model)], float)
        except (LimitError, ValueError):
            return None
        tm, cov = model_covariance(model, self.model_settings)
        spot = predict_spots(self.kin, MirrorOptics.from_config(self.heliostat.mirror), tm.values, cov,
                             steps, self.aim_point[None], self.frame,
                             floor_rad=2e-3 * self.model_settings.noise_mrad, **self._light(source))
        position = float(spot.position_sigma_m[0, 0])
        if model is None:
            position = max(position, self.first_light_sigma_m())
        return float(spot.sigma_m[0, 0]), position

    def _light(self, source) -> dict:
        if isinstance(source, LampSource):
            return {"lamp": np.asarray(source.position_enu_m, float), "lamp_diameter_m": source.diameter_m}
        return {"sun_dir": self.source_dir, "sun_angle_rad": 1e-3 * source.angular_diameter_mrad}

    def first_light_sigma_m(self) -> float:
        """1-σ (m, per axis) of where the beam of a heliostat never measured lands: its normal's
        ``search.normal_sigma_mrad`` doubled by the reflection, at the aim point's distance —
        once the field's misses know, their σ, at least half of that; 0 without a search."""
        if self.search is None:
            return 0.0
        beam = 2.0 * self.search.normal_sigma_mrad
        known = self.field_misses.expected() if self.field_misses is not None else None
        if known is not None:
            beam = max(known[1], beam / 2.0)
        return 1e-3 * beam * float(np.linalg.norm(self.aim_point - self.heliostat_pos))

    def search_pattern(self, model: ModelRecord | None) -> np.ndarray:
        """The beam search's look offsets (N, 2), m (u, v) from the aim point in the target
        plane, nearest first (:mod:`controller.geometry.search_pattern`): steps of the view less
        the overlap of ``search.overlap_sigma`` spot σ, out to ``search.extent_sigma`` σ of the
        spot's position, about the aim point — for a heliostat without a model, once the field's
        misses know, about where they put its beam (the first point, then). Empty without a search."""
        if self.search is None:
            return np.zeros((0, 2))
        spot, position = self.spot_sigmas_m(self.source, model) or (0.0, self.first_light_sigma_m())
        step = search_steps((self.frame.width_m, self.frame.height_m), spot, self.search.overlap_sigma)
        self.search_step_m = step
        reach = self.search.extent_sigma * position
        known = self.field_misses.expected() if self.field_misses is not None and model is None else None
        # The beam lands at (look + miss): to see it, look at −miss.
        centre = (0.0, 0.0) if known is None else tuple(-1e-3 * m * float(np.linalg.norm(
            self.aim_point - self.heliostat_pos)) for m in known[0])
        return spiral_offsets(step, (reach, reach), 100_000) + np.asarray(centre)

    def search_pose(self, offset_m, model: ModelRecord | None, start: tuple[int, int] | None
                    ) -> tuple[int, int] | None:
        """Steps that put the beam at ``offset_m`` (u, v, m) from the aim point, or None when they
        are out of reach, the slew there from ``start`` (or the pose itself) would put the beam
        on another target or into a person zone (beam safety, as predicted), or the spot there
        could reach another target's camera view (:meth:`_footprint_m`): a look is a guess at
        where the beam is, and that target's own captures go on meanwhile."""
        point = self.aim_point + float(offset_m[0]) * self.frame.u + float(offset_m[1]) * self.frame.v
        try:
            pose = self._steps(point, model)
        except (LimitError, ValueError):
            return None
        lim = self.heliostat.axes
        if not (lim.azimuth.soft_limits.min_steps <= pose[0] <= lim.azimuth.soft_limits.max_steps
                and lim.elevation.soft_limits.min_steps <= pose[1] <= lim.elevation.soft_limits.max_steps):
            return None
        sweep = self._sweep(start, pose) if start is not None else np.asarray([pose], float)
        if self.on_other_target(sweep).any() or self.in_zone(sweep).any():
            return None
        if self.others and self._on_others(*self.rays([pose]), self._footprint_m(model))[0]:
            return None
        return pose

    def path_margin_m(self) -> np.ndarray:
        """A slew keeps its spot out of every view (another beam may be measured there): the central
        ray at least the spot's footprint beyond a view's edges (:meth:`_footprint_m`: 3σ of its size
        and position plus :data:`PARK_MARGIN_M`), beside the view at least where it parks less 0.1 m
        (:meth:`park_clearance_m`: its standby lies just outside), ≥ 2 m beyond the target's (u, v, m)."""
        return self._margins()[0]

    def view_margin_m(self) -> np.ndarray:
        """:meth:`path_margin_m` less :data:`PARK_MARGIN_M` (≥ 2 m): this close the spot is in a view."""
        return self._margins()[1]

    def _margins(self) -> np.ndarray:
        def margins() -> np.ndarray:  # with a model: without one the search explores, _footprint_m
            foot, m = self._footprint_m(self.model), self.model
            park = self.park_clearance_m(self.source, m) - self.target.width_m / 2 if m else 0
            aside = max(foot[0], park if np.isfinite(park) else 0)  # (+∞: no park beside this view)
            path, view = [max(foot[0], aside - 0.1), foot[1]], np.array([aside, foot[1]]) - PARK_MARGIN_M
            return np.maximum(2.0, [path, view])
        key, owners = self._clearance_key(self.source, self.model), (self.heliostat, self.model_settings)
        return _SPOTS.get(key, owners, margins)

    def _footprint_m(self, model: ModelRecord | None) -> np.ndarray:
        """How far (u, v, m) beyond another target's edges its camera may see this heliostat's
        spot: 3σ of the spot's size and, with a model, of its position (:meth:`spot_sigmas_m`),
        plus :data:`PARK_MARGIN_M` and as much as this view exceeds its target on each axis
        (other cameras taken to frame theirs alike). Without a model the position is what the
        search explores (first-light σ of metres would refuse every look near another target)."""
        sigmas = self.spot_sigmas_m(self.source, model) if model is not None else None
        spot, position = sigmas or (0.0, 0.0)
        f, t = self.frame, self.target  # the view beyond its target on each side
        excess = np.maximum([f.width_m - t.width_m, f.height_m - t.height_m], 0.0) / 2.0
        return SIGMAS * (spot + position) + PARK_MARGIN_M + excess

    def _steps(self, point: np.ndarray, model: ModelRecord | None) -> tuple[int, int]:
        if not np.isfinite(point).all():  # park_clearance_m: no park beside the view in reach
            raise LimitError(f"heliostat {self.heliostat.id}: no standby beside the view is in reach")
        return _AIMS.get(self._aim_key(point, model), (self.heliostat,),
                         lambda: steps_to_aim(self.kin, model, self.source_dir, point, self.source_pos))

    def _aim_key(self, point, model: ModelRecord | None) -> tuple:
        return (id(self.heliostat), None if model is None else tuple(model.params.items()),
                np.asarray(point, float).tobytes(), self.source_dir.tobytes(), self.source_pos)

    def aim_steps(self, model: ModelRecord | None) -> tuple[int, int]:
        """Steps onto the aim point; UnsafePath when the beam there, or on the approach from
        standby, would enter a person zone (nothing has moved yet)."""
        return self.kept(("aim", self._aim_key(self.aim_point, model)), lambda: self._aim_steps(model))

    def _aim_steps(self, model: ModelRecord | None) -> tuple[int, int]:
        aim = self._steps(self.aim_point, model)
        if self.zone_ids:
            sweep = self._sweep(self.standby_steps(model), aim)
            # All poses traced at once; the first that enters a zone is named.
            inside = self.in_zone(sweep)
            for pose in sweep[int(np.argmax(inside)):] if inside.any() else ():
                zone = self.beam_in_zone(*pose)
                if zone is not None:
                    raise UnsafePath(f"{self.heliostat.id}: the approach to the aim point {aim} would send "
                                     f"the beam into person zone {zone!r}")
        return aim

    def standby_steps(self, model: ModelRecord | None, point=None) -> tuple[int, int]:
        """Steps onto the standby point (or ``point``, m ENU); UnsafePath when the beam there
        would enter a person zone."""
        point = self.standby_point if point is None else point
        return self.kept(("standby", self._aim_key(point, model)), lambda: self._standby_steps(point, model))

    def _standby_steps(self, point, model: ModelRecord | None) -> tuple[int, int]:
        standby = self._steps(point, model)
        zone = self.beam_in_zone(*standby)
        if zone is not None:
            raise UnsafePath(f"{self.heliostat.id}: the standby pose {standby} would send the beam into "
                             f"person zone {zone!r}")
        return standby

    def leave_steps(self, model: ModelRecord | None, seen=None) -> tuple[int, int]:
        """Steps onto the standby point on the side of the target nearest the aim point
        (:meth:`side_points`): the standby point itself when the aim is on the target's centre
        line. ``seen`` (pose, centroid m ENU): the run's last measurement. Where ``model`` puts
        that pose's beam and where it was seen lie d apart (a fit that could not reconcile its
        measurements, or a centroid off): the point lies d farther out, so that the spot parks
        clear of the view whichever was right. LimitError, ValueError or UnsafePath (a person
        zone) when it cannot be reached safely."""
        f, off = self.frame, float((self.aim_point - self.frame.center) @ self.frame.u)
        point = self.standby_point if off == 0.0 else \
            [p for p in self.side_points() if float((p - f.center) @ f.u) * off > 0][0]
        if seen is not None and seen[1] is not None and model is not None:
            hit = self.plane_uv([seen[0]], TrackingModel.from_dict(model.params).values)[0]
            d = float(np.hypot(*(hit - [(np.asarray(seen[1], float) - f.center) @ a for a in (f.u, f.v)])))
            point = point + (d if d > LEAVE_MIN_M else 0.0) * np.sign(float((point - f.center) @ f.u)) * f.u
        return self.standby_steps(model, point)

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
        (:func:`controller.geometry.model.fit.fit_model`). ``prior`` (the last model) is kept
        when there is nothing to fit or the data identify no term. Under a beam search the fitted
        model is from then on what the beam-safety checks trace the ray with (its park after the
        run): the nominal kinematics put a new heliostat's beam metres from where it is."""
        model = fit_measurements(self.kin, measurements, self.model_settings) or prior
        if self.search is not None and model is not None:
            self.ray_model = TrackingModel.from_dict(model.params).values
        return model


def steps_to_aim(kin: HeliostatKinematics, model: ModelRecord | None, source_dir: np.ndarray,
                 point: np.ndarray, lamp_position=None) -> tuple[int, int]:
    """Motor steps that reflect light from ``source_dir`` (unit ENU, towards the source) onto
    ``point`` (m ENU): with the fitted tracking-error ``model`` (the bisector normal made the
    *actual* normal, :func:`controller.geometry.model.tracking.model_aim`), or the nominal
    kinematics without one. For a lamp at ``lamp_position`` (m ENU) the model takes its direction
    from the model's mirror centre. LimitError when the pose is out of reach."""
    if model is None:
        return kin.aim(source_dir, point)
    return model_aim(kin, TrackingModel.from_dict(model.params), source_dir, point,
                     lamp_position=lamp_position)


def model_covariance(model: ModelRecord | None, settings: ModelSettings) -> tuple[TrackingModel, np.ndarray]:
    """(model, covariance SI²) of a stored model; without one (or one that predates
    covariances) the prior's model and covariance (``calibration.model``: the field's prior or
    the documented one, :func:`controller.calibration.cycle.model_update.model_prior`)."""
    cov = None if model is None else model.detail.get("covariance_si")
    if cov is None or len(cov) != len(TERMS):
        prior = model_prior(settings)
        base = TrackingModel(prior.mean) if model is None else TrackingModel.from_dict(model.params)
        return base, np.diag(prior.sigma**2)
    return TrackingModel.from_dict(model.params), np.asarray(cov, float)


def clearances(items: list[tuple[GeometryPointing, object, ModelRecord | None]]) -> np.ndarray:
    """The park clearances (m) of ``items`` (pointing, source, model), which share a source,
    a view and model settings: one batch."""
    p0, source = items[0][0], items[0][1]
    pairs = [model_covariance(m, p.model_settings) for p, _, m in items]
    values = np.array([tm.values for tm, _ in pairs])
    covs = np.array([cov for _, cov in pairs])
    first = np.array([p.first_light_sigma_m() if m is None else unexplained_sigma_m(
        m, p.model_settings.noise_mrad, p.frame.center - p.heliostat_pos) for p, _, m in items])
    kin = KinStack.of([p.kin for p, _, _ in items])
    optics = MirrorOptics.stack([p.heliostat.mirror for p, _, _ in items])
    return park_clearances_m(kin, optics, values, covs, p0.frame, PARK_MARGIN_M, position_floor_m=first,
                             floor_rad=2e-3 * p0.model_settings.noise_mrad, **p0._light(source))
