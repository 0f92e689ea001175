"""The candidate geometries of one heliostat tonight, evaluated all at once, with their spots.

For every lamp of ``calibration.lamps`` × every aim point of the heliostat's target tonight
(a *candidate*), with the heliostat's present model and covariance:

* the steps the model aims with (:func:`controller.geometry.pose_batch.aim_steps`) — out of
  reach drops it;
* the lamp's incidence on the mirror — beyond :data:`MAX_INCIDENCE_DEG` the lamp grazes the
  mirror (a faint, smeared spot) and drops it;
* the beam's way to the aim point — entering a person zone drops it;
* H, what the measurement observes of the model (:mod:`controller.geometry.design`, Eq. 1);
* the predicted spot (:mod:`controller.geometry.spot`): its size from the distance, the mirror
  and the lamp's angular size, its centre's uncertainty from the model's covariance — a
  candidate whose 3σ spot would leave the camera's view (less ``planner.view_margin_m``) is
  not measurable and drops it.

What remains is what the planner chooses from; when nothing remains the heliostat has no
measurable geometry tonight and :class:`Candidates` says why.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller.config import LampSource, PlantConfig
from controller.geometry.design import tangents_batch
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model.tracking import TrackingModel
from controller.geometry.pose_batch import KinStack, aim_steps, forward_jacobian, normal_and_center, perturbed
from controller.geometry.spot import MirrorOptics, PredictedSpot, predict_spots
from controller.geometry.target_frame import TargetFrame
from controller.geometry.vectors import unit
from controller.geometry.zones import rays_enter_any, zone_boxes

MAX_INCIDENCE_DEG = 75.0  # beyond this the lamp grazes the mirror: a faint, smeared spot


@dataclass(frozen=True)
class TargetView:
    """A target as its camera sees it: the frame of the camera's pixel grid, the view's
    half-size (u, v) m and the aim grid over it ((row, col), point m ENU)."""

    id: str
    frame: TargetFrame
    half_view_m: np.ndarray
    cells: tuple[tuple[int, int], ...]
    points: np.ndarray  # (A, 3)


class FieldGeometry:
    """What every heliostat's candidates share: the lamps, the targets' views and aim grids, the
    person zones, the calibration target's centre and the planner's sun directions."""

    def __init__(self, cfg: PlantConfig, sun_dirs: np.ndarray, aim_grid) -> None:
        self.cfg = cfg
        self.sun = np.asarray(sun_dirs, float)
        self.lamps = [s for s in (cfg.light_source(i) for i in cfg.calibration.planned_lamps())
                      if isinstance(s, LampSource)]
        self.views: dict[str, TargetView] = {}
        for tid in cfg.calibration.parallel_targets():
            t, cam = cfg.target(tid), cfg.camera_of(tid)
            frame = TargetFrame.from_config(t, (cam.height_px, cam.width_px))
            grid = aim_grid(cfg, tid)
            self.views[tid] = TargetView(tid, frame, np.array([frame.width_m, frame.height_m]) / 2.0,
                                         tuple(c for c, _ in grid), np.array([p for _, p in grid], float))
        self.zones = zone_boxes(cfg.person_zones)
        self.centre = np.asarray(cfg.target().center_enu_m, float)
        self.margin_m = cfg.calibration.planner.view_margin_m
        # The beam error no covariance knows (spot Eq. 3): the measured normal's noise, doubled.
        self.floor_rad = 2e-3 * cfg.calibration.model.noise_mrad


@dataclass(frozen=True, eq=False)  # numpy fields
class Candidates:
    """The measurable candidates of one heliostat on one target (module docstring): lamp ids,
    aim points (C, 3), grid cells, steps (C, 2), H (C, 2, p) and the predicted spots; ``m``
    the heliostat's daytime weight (design Eq. 3); ``why`` says why none is measurable."""

    lamps: list[str]
    points: np.ndarray
    cells: list[tuple[int, int]]
    steps: np.ndarray
    h: np.ndarray
    spots: PredictedSpot
    m: np.ndarray
    why: str | None = None


def evaluate(geo: FieldGeometry, heliostat_id: str, model: TrackingModel, cov: np.ndarray,
             target: str) -> Candidates:
    """The candidates of ``heliostat_id`` on ``target`` with its ``model`` and covariance ``cov``
    (module docstring)."""
    return evaluate_many(geo, [(heliostat_id, model, cov, target)])[0]


def evaluate_many(geo: FieldGeometry,
                  tasks: list[tuple[str, TrackingModel, np.ndarray, str]]) -> list[Candidates]:
    """:func:`evaluate` for each ``(heliostat id, model, covariance, target)`` of ``tasks``, all
    at once (:class:`controller.geometry.pose_batch.KinStack`): a chunk of a field costs a few
    hundred array operations, not a few hundred per heliostat."""
    hs = [geo.cfg.heliostat(hid) for hid, *_ in tasks]
    kin = KinStack.of([HeliostatKinematics.from_config(h) for h in hs])
    values = np.array([m.values for _, m, _, _ in tasks], float)  # (H, p)
    covs = np.array([c for _, _, c, _ in tasks], float)  # (H, p, p)
    views = [geo.views[t] for *_, t in tasks]
    m = _daytime_weights(geo, kin, values)
    if not geo.lamps:
        return [_none(mi, "no lamp of calibration.lamps to plan with") for mi in m]
    a_count = len(views[0].points)
    lamp_ids = [lp.id for lp in geo.lamps for _ in range(a_count)]
    lamp_pos = np.repeat(np.array([lp.position_enu_m for lp in geo.lamps], float), a_count, axis=0)
    lamp_d = np.repeat(np.array([lp.diameter_m for lp in geo.lamps], float), a_count)
    points = np.array([np.tile(v.points, (len(geo.lamps), 1)) for v in views])  # (H, K, 3)
    steps, ok = aim_steps(kin.shaped(2), values[:, None, :], points, lamp=lamp_pos)
    reach = ok.copy()
    n, c = normal_and_center(kin.shaped(3), perturbed(values)[:, :, None, :], steps[:, None])  # (H, P, K, 3)
    s = unit(lamp_pos - c)
    ok &= np.sum(s[:, 0] * n[:, 0], axis=-1) >= math.cos(math.radians(MAX_INCIDENCE_DEG))
    lit = ok.copy()
    if len(geo.zones):
        # The beam runs from the mirror to the aim point, where the target stops it.
        pos = np.broadcast_to(np.array([h.position_enu_m for h in hs], float)[:, None], points.shape)
        ok &= ~rays_enter_any(pos.reshape(-1, 3), (points - pos).reshape(-1, 3), geo.zones, 1.0
                              ).reshape(ok.shape)
    clear = ok.copy()
    # H of design Eq. (1): the tangential components of the normal less the normal the spot implies.
    implied = unit(s + unit(points[:, None] - c))
    hh = forward_jacobian(np.einsum("hkij,hpkj->hpki", tangents_batch(n[:, 0]), n - implied), axis=1)
    optics = MirrorOptics(*(np.array([getattr(MirrorOptics.from_config(h.mirror), f) for h in hs])[:, None]
                            for f in ("width_m", "height_m", "focal_m", "slope_error_rad")))
    frames = _FrameStack(*(np.array([getattr(v.frame, f) for v in views])[:, None]
                           for f in ("center", "normal", "u", "v")))
    spots = predict_spots(kin, optics, values, covs, steps, points, frames, lamp=lamp_pos[None],
                          lamp_diameter_m=lamp_d, floor_rad=geo.floor_rad)
    half = np.array([v.half_view_m for v in views])[:, None]
    ok &= np.all(spots.reach_m() + geo.margin_m <= half, axis=-1)
    out = []
    for i, view in enumerate(views):
        idx = np.flatnonzero(ok[i])
        sp = PredictedSpot(spots.offset_m[i], spots.sigma_m[i], spots.position_sigma_m[i])
        why = None if len(idx) else _why(reach[i], lit[i], clear[i], sp, view, geo.margin_m)
        kept = PredictedSpot(sp.offset_m[idx], sp.sigma_m[idx], sp.position_sigma_m[idx])
        out.append(Candidates([lamp_ids[k] for k in idx], points[i, idx],
                              [view.cells[k % a_count] for k in idx], steps[i, idx], hh[i, idx], kept, m[i],
                              why))
    return out


@dataclass(frozen=True, eq=False)  # numpy fields
class _FrameStack:
    """The target planes of a chunk of heliostats, each (H, 1, 3): what predict_spots reads of a frame."""

    center: np.ndarray
    normal: np.ndarray
    u: np.ndarray
    v: np.ndarray


def _daytime_weights(geo: FieldGeometry, kin: KinStack, values: np.ndarray) -> np.ndarray:
    """M of design Eq. (3) for each heliostat, (H, p, p): its beam's sensitivity over the
    planner's sun positions, aiming at the calibration target's centre
    (:func:`controller.geometry.design.beam_jacobians` for a stack)."""
    h, sun = len(values), geo.sun
    if not len(sun):
        return np.full((h, values.shape[1], values.shape[1]), np.nan)
    aims = np.broadcast_to(geo.centre, (h, len(sun), 3))
    steps, ok = aim_steps(kin.shaped(2), values[:, None, :], aims,
                          source_dirs=np.broadcast_to(sun, aims.shape))
    n, c = normal_and_center(kin.shaped(3), perturbed(values)[:, :, None, :], steps[:, None])  # (H, P, S, 3)
    beam = 2.0 * np.sum(sun * n, axis=-1, keepdims=True) * n - sun - unit(geo.centre - c)
    a = forward_jacobian(beam, axis=1) * ok[:, :, None, None]  # (H, S, 3, p); unreachable: left out
    count = ok.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.einsum("hkip,hkiq->hpq", a, a) / np.where(count > 0, count, np.nan)[:, None, None]


def _none(m: np.ndarray, why: str) -> Candidates:
    empty = np.empty((0, 2))
    return Candidates([], np.empty((0, 3)), [], np.empty((0, 2), np.int64), np.empty((0, 2, m.shape[0])),
                      PredictedSpot(empty, empty, empty), m, why)


def _why(reach: np.ndarray, lit: np.ndarray, clear: np.ndarray, spots: PredictedSpot, view: TargetView,
         margin_m: float) -> str:
    """Why no candidate is measurable: how many fell at each check, and for those that fell at
    the camera's view how close the best came (3σ reach of the spot against the half-view)."""
    parts = []
    if (~reach).any():
        parts.append(f"{int((~reach).sum())} out of reach")
    if (reach & ~lit).any():
        parts.append(f"{int((reach & ~lit).sum())} with the lamp grazing the mirror "
                     f"(incidence over {MAX_INCIDENCE_DEG:g}°)")
    if (lit & ~clear).any():
        parts.append(f"{int((lit & ~clear).sum())} whose beam enters a person zone")
    big = np.flatnonzero(clear)
    if len(big):
        excess = np.max((spots.reach_m() + margin_m) / view.half_view_m, axis=-1)
        k = big[int(np.argmin(excess[big]))]
        parts.append(f"{len(big)} whose 3σ spot leaves the camera's view of {view.id} (best: reaches "
                     f"{spots.reach_m()[k][0]:.1f} × {spots.reach_m()[k][1]:.1f} m of the "
                     f"{view.half_view_m[0]:.1f} × {view.half_view_m[1]:.1f} m half-view less "
                     f"{margin_m:g} m; spot σ {max(spots.sigma_m[k]):.2f} m, position σ "
                     f"{max(spots.position_sigma_m[k]):.2f} m)")
    return f"no measurable geometry on {view.id}: of {len(reach)} candidates, " + ", ".join(parts)
