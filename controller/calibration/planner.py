"""The nightly planner: which geometries each heliostat is measured at tonight.

A *geometry* is a lamp, a target and an aim point on it (the aim grid of
``calibration.aim_grid``, over each of ``calibration.targets``). Each one puts the heliostat
at another pose, and the spread of poses is what lets the fit separate the model's terms.
For every heliostat the planner

1. lists the candidate geometries it can take: each lit lamp × each aim point of tonight's
   target(s), kept when the heliostat reaches the pose within its soft limits with its
   present model and the lamp lights the mirror's front (incidence below :data:`MAX_INCIDENCE_DEG`),
   and whose beam on its way to the aim point enters no person zone (``person_zones``; the
   approach from standby is checked again by the cycle before anything moves);
2. scores them by the expected reduction of its *daytime* pointing variance
   (:mod:`controller.geometry.design`, Eq. 1-2) from its present model covariance, over
   ``calibration.planner.sun_positions`` positions of the yearly sun path;
3. picks ``geometries_per_night`` greedily — or ``check_geometries`` when its predicted
   daytime error is already within ``tolerance_mrad``.

Each choice is explained by a :class:`PlanItem` (expected gain, predicted RMS before and
after), stored in the ``plan`` table. :func:`round_robin` is the fixed schedule the planner
is measured against (``benchmarks/bench_planner.py``): the same number of measurements,
cycling through the same candidates in a fixed order.

Beam safety is not relaxed: the planned geometries are run by the ordinary cycle, which
approaches from standby and takes the target through its gate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller.calibration.daytime import model_covariance, sun_path
from controller.calibration.records import ModelRecord
from controller.config import LampSource, PlantConfig
from controller.errors import LimitError
from controller.geometry.aiming import source_direction
from controller.geometry.design import (
    beam_jacobians,
    daytime_variance,
    fixed_design,
    greedy_design,
    normal_jacobian,
)
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.target_frame import TargetFrame
from controller.geometry.tracking_model import TrackingModel, model_aim, model_normal
from controller.geometry.zones import zone_boxes, zone_entered

MAX_INCIDENCE_DEG = 75.0  # beyond this the lamp grazes the mirror: a faint, smeared spot


@dataclass(frozen=True)
class Geometry:
    """A candidate: ``lamp`` id, aim point (m ENU) with its grid cell (row, col), the steps
    the heliostat would take there with its present model, and the ``target`` id (None: the
    calibration target)."""

    lamp: str
    aim_enu: tuple[float, float, float]
    cell: tuple[int, int]
    steps: tuple[int, int]
    target: str | None = None


@dataclass(frozen=True)
class PlanItem:
    """One planned measurement and why: expected gain (rad² of daytime variance) and the
    heliostat's predicted daytime RMS before and after it (mrad); ``rank`` 1 = first pick."""

    heliostat_id: str
    night: str
    geometry: Geometry
    rank: int
    gain: float
    predicted_before_mrad: float
    predicted_after_mrad: float
    strategy: str = "design"


def aim_points(cfg: PlantConfig, target: str | None = None) -> list[tuple[tuple[int, int], np.ndarray]]:
    """The aim grid over ``target`` (default: the calibration target): ((row, col), point m
    ENU), row 0 at the top."""
    g = cfg.calibration.aim_grid
    t = cfg.target(target)
    frame = TargetFrame.from_config(t, (1, 1))
    half_w = max(0.0, t.width_m / 2 - g.margin_m)
    half_h = max(0.0, t.height_m / 2 - g.margin_m)
    xs = np.linspace(-half_w, half_w, g.cols) if g.cols > 1 else np.zeros(1)
    ys = np.linspace(-half_h, half_h, g.rows) if g.rows > 1 else np.zeros(1)
    return [((r, c), frame.center + x * frame.u + y * frame.v)
            for r, y in enumerate(ys) for c, x in enumerate(xs)]


def candidates(cfg: PlantConfig, heliostat_id: str, model: TrackingModel,
               targets: tuple[str, ...] | None = None) -> list[Geometry]:
    """Every geometry of the module docstring's step 1 for one heliostat, on ``targets``
    (default: every target of ``calibration.targets``)."""
    h = cfg.heliostat(heliostat_id)
    kin = HeliostatKinematics.from_config(h)
    pos = np.asarray(h.position_enu_m, float)
    zones = zone_boxes(cfg.person_zones)
    out = []
    for lamp_id in cfg.calibration.planned_lamps():
        lamp = cfg.light_source(lamp_id)
        if not isinstance(lamp, LampSource):
            continue
        s = np.asarray(source_direction(lamp, pos), float)
        for tid, (cell, point) in ((t, a) for t in targets or cfg.calibration.parallel_targets()
                                   for a in aim_points(cfg, t)):
            try:
                steps = model_aim(kin, model, s, point)
            except (LimitError, ValueError):
                continue
            n = model_normal(kin, model, *steps)
            if math.degrees(math.acos(min(1.0, float(s @ n)))) > MAX_INCIDENCE_DEG:
                continue
            # The beam runs from the mirror to the aim point, where the target stops it.
            if len(zones) and zone_entered(pos, point - pos, zones, 1.0) is not None:
                continue
            out.append(Geometry(lamp_id, tuple(float(v) for v in point), cell,
                                (int(steps[0]), int(steps[1])), tid))
    return out


def planner_sun(cfg: PlantConfig) -> np.ndarray:
    """The sun directions the planner scores against: ``planner.sun_positions`` spread evenly
    over the yearly evaluation path (:func:`controller.calibration.daytime.sun_path`)."""
    d = sun_path(cfg.site).directions
    n = min(len(d), cfg.calibration.planner.sun_positions)
    return d[np.linspace(0, len(d) - 1, n).round().astype(int)]


def plan_heliostat(cfg: PlantConfig, heliostat_id: str, record: ModelRecord | None, night: str,
                   sun_dirs: np.ndarray, *, strategy: str = "design", offset: int = 0,
                   targets: tuple[str, ...] | None = None) -> list[PlanItem]:
    """Tonight's measurements of one heliostat (module docstring) on ``targets`` (default:
    all). ``strategy`` ``design`` (by expected gain) or ``round-robin`` (:func:`round_robin`,
    starting at candidate ``offset``)."""
    cal = cfg.calibration
    model, cov = model_covariance(record, cal.model.prior_sigma)
    kin = HeliostatKinematics.from_config(cfg.heliostat(heliostat_id))
    geos = candidates(cfg, heliostat_id, model, targets)
    if not geos:
        return []
    a = beam_jacobians(kin, model, sun_dirs, np.asarray(cfg.target().center_enu_m, float))
    v = daytime_variance(a, cov)
    predicted = 1e3 * math.sqrt(v) if math.isfinite(v) else float("inf")
    n = cal.planner.check_geometries if predicted <= cal.tolerance_mrad else cal.planner.geometries_per_night
    if n == 0:
        return []
    hs = [normal_jacobian(kin, model, *g.steps, None, np.asarray(g.aim_enu),
                          np.asarray(cfg.light_source(g.lamp).position_enu_m, float)) for g in geos]
    noise = cal.model.noise_mrad * 1e-3
    if strategy == "round-robin":
        picks, _ = fixed_design(cov, hs, a, noise, round_robin(len(geos), n, offset))
    elif strategy == "design":
        picks, _ = greedy_design(cov, hs, a, noise, n)
    else:
        raise ValueError(f"unknown planning strategy {strategy!r}")
    return [PlanItem(heliostat_id, night, geos[p.index], rank, p.gain, p.rms_before_mrad, p.rms_after_mrad,
                     strategy) for rank, p in enumerate(picks, start=1)]


def round_robin(count: int, n: int, offset: int) -> list[int]:
    """``n`` candidate indices of ``count`` taken in their fixed order from ``offset`` on
    (wrapping): the schedule without a model of what each measurement is worth."""
    return [(offset + i) % count for i in range(min(n, count))]


def plan_night(cfg: PlantConfig, models: dict[str, ModelRecord | None], night: str, *,
               strategy: str = "design", night_index: int = 0) -> list[PlanItem]:
    """Tonight's plan for the heliostats in ``models`` (id -> latest model or None). The queue
    is distributed over ``calibration.targets`` (which run in parallel): heliostat i takes
    tonight target (i + night_index) mod n, so each target gets its share and each heliostat
    another target the next night."""
    sun = planner_sun(cfg)
    targets = cfg.calibration.parallel_targets()
    out: list[PlanItem] = []
    for i, (hid, rec) in enumerate(models.items()):
        per = cfg.calibration.planner.geometries_per_night
        out += plan_heliostat(cfg, hid, rec, night, sun, strategy=strategy, offset=night_index * per,
                              targets=(targets[(i + night_index) % len(targets)],))
    return out
