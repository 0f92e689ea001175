"""Which heliostats may stay where they are when a lamp changes: the whole field at once.

A lamp change (:mod:`controller.calibration.campaign.lamp_change`) leaves a heliostat that is
not in the new lamp's passes where it is when its beam under the new lamp lands farther from
every target than its standby beam would (:meth:`GeometryPointing.park_clearance_m`: the
view's half-width plus 3σ of the parked spot's size and position) and enters no person zone.
Checked one heliostat at a time that costs a model-based aim solve and a spot prediction each,
about 2 ms: 20 CPU seconds per lamp change of a 10,000-heliostat field. Here the same
quantities are evaluated for the whole field in a few hundred array operations
(:mod:`controller.geometry.pose_batch`, the batched spot prediction of Eq. 1-3 in
:mod:`controller.geometry.spot`).

Only a certain answer is taken from the batch: a heliostat stays when its beam's free distance
(below) exceeds the margin by more than :data:`BAND_M`; every other heliostat, and every one
whose aim point or pose is out of reach, is decided one at a time exactly as before. The
batch's aim solve differs from the scalar one by a step at most (the nominal kinematics take
the lamp's direction from the pivot, the batch from the mirror centre), which moves a margin
by millimetres, far inside the band.

Free distance of a ray from a target of width w and height h (m), hit at (u, v) in its plane:
max(|u| − w/2, |v| − h/2), infinite when the ray points away from the plane; the beam is off
the target grown by a margin m exactly when that distance exceeds m
(:meth:`BeamSafety._depths`).
"""

from __future__ import annotations

import numpy as np

from controller.calibration.cycle.model_update import unexplained_sigma_m
from controller.calibration.cycle.pointing import PARK_MARGIN_M, model_covariance
from controller.calibration.records import ModelRecord
from controller.config import PlantConfig
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model.tracking import TrackingModel
from controller.geometry.pose_batch import KinStack, aim_steps, normal_and_center
from controller.geometry.spot import MirrorOptics, park_clearances_m
from controller.geometry.target_frame import TargetFrame
from controller.geometry.zones import rays_enter_any, zone_boxes

BAND_M = 0.5  # a batched margin is trusted only this far (m) from the beam's free distance


def certainly_safe(cfg: PlantConfig, lamp: str, poses: dict[str, tuple[int, int]],
                   models: dict[str, ModelRecord | None], frame: TargetFrame) -> set[str]:
    """The heliostats of ``poses`` (id → present steps) whose beam under ``lamp`` at that pose
    is certainly as far from every target as their standby beam beside the calibration target
    would be, and in no person zone (module docstring); ``models`` their latest models,
    ``frame`` the calibration target's view. The others are for the caller to check one by
    one."""
    ids = list(poses)
    if not ids:
        return set()
    source = cfg.light_source(lamp)
    hs = [cfg.heliostat(h) for h in ids]
    kin = KinStack.of([HeliostatKinematics.from_config(h) for h in hs])
    lamp_pos = np.asarray(source.position_enu_m, float)
    ray_values = np.array([(TrackingModel.zero() if models[h] is None
                            else TrackingModel.from_dict(models[h].params)).values for h in ids])
    n, c = normal_and_center(kin.shaped(2), ray_values[:, None, :], np.array([poses[h] for h in ids],
                                                                            float)[:, None, :])
    n, c = n[:, 0], c[:, 0]
    # The lamp's light at each pose's mirror centre, as BeamSafety.rays traces it.
    to_lamp = lamp_pos - c
    to_lamp /= np.linalg.norm(to_lamp, axis=-1, keepdims=True)
    beam = 2.0 * np.sum(n * to_lamp, axis=-1, keepdims=True) * n - to_lamp
    free = np.full(len(ids), np.inf)
    for t in cfg.targets:
        f = TargetFrame.from_config(t, (1, 1))
        with np.errstate(divide="ignore", invalid="ignore"):
            along = ((f.center - c) @ f.normal) / (beam @ f.normal)
            hit = c + along[:, None] * beam - f.center
            d = np.maximum(np.abs(hit @ f.u) - t.width_m / 2, np.abs(hit @ f.v) - t.height_m / 2)
        free = np.minimum(free, np.where(np.isfinite(along) & (along >= 0.0), d, np.inf))
    known = np.all(np.isfinite(c) & np.isfinite(beam), axis=-1)  # NaN: a pose out of the actuators' reach
    if cfg.person_zones:
        with np.errstate(divide="ignore", invalid="ignore"):
            along = ((frame.center - c) @ frame.normal) / (beam @ frame.normal)
        hit = c + along[:, None] * beam - frame.center
        on = (np.isfinite(along) & (along >= 0.0) & (np.abs(hit @ frame.u) <= cfg.target().width_m / 2)
              & (np.abs(hit @ frame.v) <= cfg.target().height_m / 2))
        known &= ~rays_enter_any(c, beam, zone_boxes(cfg.person_zones), np.where(on, along, np.inf))
    margin = _stay_margin(cfg, ids, hs, kin, models, lamp_pos, source.diameter_m, frame)
    return {h for h, k, d, m in zip(ids, known, free, margin, strict=True) if k and np.isfinite(m)
            and d > m + BAND_M}


def _stay_margin(cfg: PlantConfig, ids: list[str], hs: list, kin: KinStack,
                 models: dict[str, ModelRecord | None], lamp_pos: np.ndarray, lamp_diameter_m: float,
                 frame: TargetFrame) -> np.ndarray:
    """Each heliostat's margin to stay (m; NaN where its aim point is out of reach): its standby
    offset beside the calibration target's centre less half the largest target, at least 2 m —
    :class:`GeometryPointing`'s ``standby_offset_m`` (the configured offset, or the park
    clearance when larger) as the lamp change uses it."""
    settings = cfg.calibration.model
    pairs = [model_covariance(models[h], settings) for h in ids]
    values = np.array([tm.values for tm, _ in pairs])
    covs = np.array([cov for _, cov in pairs])
    aim = np.broadcast_to(np.asarray(cfg.target().center_enu_m, float), (len(ids), 1, 3))
    _, ok = aim_steps(kin.shaped(2), values[:, None, :], aim, lamp=lamp_pos)
    # GeometryPointing.park_clearance_m for each heliostat
    unexplained = np.array([unexplained_sigma_m(models[i], settings.noise_mrad,
                                                frame.center - h.position_enu_m)
                            for i, h in zip(ids, hs, strict=True)])
    clearance = park_clearances_m(kin, MirrorOptics.stack([h.mirror for h in hs]), values, covs, frame,
                                  PARK_MARGIN_M, lamp=lamp_pos, lamp_diameter_m=lamp_diameter_m,
                                  floor_rad=2e-3 * settings.noise_mrad, position_floor_m=unexplained)
    offset = np.maximum(cfg.calibration.standby_offset_m, clearance)
    half = max(max(t.width_m, t.height_m) for t in cfg.targets) / 2
    return np.where(ok[:, 0], np.maximum(2.0, offset - half), np.nan)
