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
from controller.geometry.design import beam_jacobians, daytime_weight, tangents_batch
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.pose_batch import aim_steps, forward_jacobian, normal_and_center, perturbed
from controller.geometry.spot import MirrorOptics, PredictedSpot, predict_spots
from controller.geometry.target_frame import TargetFrame
from controller.geometry.tracking_model import TrackingModel
from controller.geometry.vectors import unit
from controller.geometry.zones import zone_boxes, zone_entered

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
    h = geo.cfg.heliostat(heliostat_id)
    kin = HeliostatKinematics.from_config(h)
    view = geo.views[target]
    fr = view.frame
    a_count = len(view.points)
    lamp_ids = [lp.id for lp in geo.lamps for _ in range(a_count)]
    lamp_xyz = np.array([lp.position_enu_m for lp in geo.lamps], float).reshape(-1, 3)
    lamp_pos = np.repeat(lamp_xyz, a_count, axis=0)
    lamp_d = np.repeat(np.array([lp.diameter_m for lp in geo.lamps], float), a_count)
    points = np.tile(view.points, (len(geo.lamps), 1))
    cells = list(view.cells) * len(geo.lamps)
    # The daytime weight: the beam's sensitivity over the planner's sun positions (design Eq. 3).
    m = daytime_weight(beam_jacobians(kin, model, geo.sun, geo.centre))
    if not len(points):
        return _none(m, "no lamp of calibration.lamps to plan with")
    steps, ok = aim_steps(kin, model.values, points, lamp=lamp_pos)
    reach = ok.copy()
    n, c = normal_and_center(kin, perturbed(model.values)[:, None, :], steps)  # (p + 1, K, 3)
    s = unit(lamp_pos - c)
    cos_i = np.sum(s[0] * n[0], axis=-1)
    ok &= cos_i >= math.cos(math.radians(MAX_INCIDENCE_DEG))
    lit = ok.copy()
    if len(geo.zones):
        pos = np.asarray(h.position_enu_m, float)
        # The beam runs from the mirror to the aim point, where the target stops it.
        for k in np.flatnonzero(ok):
            ok[k] = zone_entered(pos, points[k] - pos, geo.zones, 1.0) is None
    clear = ok.copy()
    # H of design Eq. (1): the tangential components of the normal less the normal the spot implies.
    implied = unit(s + unit(points - c))
    hh = forward_jacobian(np.einsum("kij,pkj->pki", tangents_batch(n[0]), n - implied))
    spots = predict_spots(kin, MirrorOptics.from_config(h.mirror), model.values, cov, steps, points, fr,
                          lamp=lamp_pos, lamp_diameter_m=lamp_d)
    ok &= spots.in_view(view.half_view_m, geo.margin_m)
    idx = np.flatnonzero(ok)
    why = None if len(idx) else _why(reach, lit, clear, spots, view, geo.margin_m)
    return Candidates([lamp_ids[i] for i in idx], points[idx], [cells[i] for i in idx], steps[idx], hh[idx],
                      PredictedSpot(spots.offset_m[idx], spots.sigma_m[idx], spots.position_sigma_m[idx]),
                      m, why)


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
