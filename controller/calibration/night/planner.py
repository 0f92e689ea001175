"""The nightly planner: which geometries each heliostat is measured at tonight.

A *geometry* is a lamp, a target and an aim point on it (the aim grid of
``calibration.aim_grid``, over each of ``calibration.targets``). Each one puts the heliostat
at another pose, and the spread of poses is what lets the fit separate the model's terms.
For every heliostat the planner

1. lists the candidate geometries it can take (:mod:`controller.calibration.night.candidates`):
   each lit lamp × each aim point of tonight's target(s), kept when the heliostat reaches the
   pose within its soft limits with its present model, the lamp lights the mirror's front
   (incidence below :data:`MAX_INCIDENCE_DEG`), the beam on its way to the aim point enters no
   person zone (``person_zones``; the approach from standby is checked again by the cycle
   before anything moves) and the spot is *measurable*: its predicted size and the
   uncertainty of its position (:mod:`controller.geometry.spot`) keep its 3σ footprint inside
   the camera's view, ``planner.view_margin_m`` from the edge. A heliostat left with no
   candidate has no measurable geometry tonight: it is reported (:class:`Unmeasurable`, with
   why) and not planned;
2. scores them by the expected reduction of its *daytime* pointing variance
   (:mod:`controller.geometry.design`, Eq. 1-3) from its present model covariance, over
   ``calibration.planner.sun_positions`` positions of the yearly sun path;
3. picks ``geometries_per_night`` greedily — or ``check_geometries`` when its predicted
   daytime error is already within ``tolerance_mrad``.

Each choice is explained by a :class:`PlanItem` (expected gain, predicted RMS before and
after), stored in the ``plan`` table. :func:`round_robin` is the fixed schedule the planner
is measured against (``benchmarks/bench_planner.py``): the same number of measurements,
cycling through the same candidates in a fixed order.

Each heliostat is one planning decision, independent of the others (only target time couples
them, and the target of each heliostat is fixed by its index): a large field is planned in a
pool of processes (:func:`plan_field`), with the same result as one at a time.

Beam safety is not relaxed: the planned geometries are run by the ordinary cycle, which
approaches from standby and takes the target through its gate.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from controller.calibration.night.candidates import (
    MAX_INCIDENCE_DEG,
    Candidates,
    FieldGeometry,
    evaluate,
    evaluate_many,
)
from controller.calibration.night.daytime import model_covariance, sun_path
from controller.calibration.night.workers import map_chunks
from controller.calibration.records import ModelRecord
from controller.config import PlantConfig
from controller.errors import InputError
from controller.geometry.design import fixed_design, greedy_design
from controller.geometry.model.tracking import TrackingModel
from controller.geometry.target_frame import TargetFrame

__all__ = ["MAX_INCIDENCE_DEG", "Geometry", "NightPlan", "PlanItem", "Unmeasurable", "aim_points", "assess",
           "assess_many", "candidates", "geometry_key", "plan_field", "plan_heliostat", "plan_night",
           "planner_sun", "round_robin"]


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


@dataclass(frozen=True)
class Unmeasurable:
    """A heliostat with no measurable geometry tonight, ``why`` (which checks its candidates
    failed), and its predicted daytime RMS (mrad)."""

    heliostat_id: str
    why: str
    predicted_mrad: float

    def to_json(self) -> dict:
        return {"heliostat": self.heliostat_id, "why": self.why,
                "predicted_mrad": self.predicted_mrad if math.isfinite(self.predicted_mrad) else None}


@dataclass
class NightPlan:
    """Tonight's plan: its items, the heliostats with no measurable geometry, the number of
    planning decisions (heliostats planned) and the wall seconds the planning took."""

    items: list[PlanItem]
    unmeasurable: list[Unmeasurable]
    decisions: int
    seconds: float


def check_plan(plan: list[PlanItem], cfg: PlantConfig, source: str) -> None:
    """That a stored ``plan`` (a night resumed) still fits ``cfg`` (read from ``source``): each
    lamp a lamp of ``light_sources`` with a ``lamps.channels`` channel when a panel is
    configured, each heliostat and target in the configuration. InputError naming the first
    that is not; nothing was switched or moved."""
    lamps = {s.id for s in cfg.light_sources if s.kind == "lamp"}
    channels = None if cfg.lamps is None else set(cfg.lamps.channels)
    heliostats = {h.id for h in cfg.heliostats}
    targets = {t.id for t in cfg.targets}
    for it in plan:
        g, where = it.geometry, f"{source}: night {it.night} was planned with"
        if g.lamp not in lamps:
            missing = f"lamp {g.lamp!r}, no longer a lamp of light_sources"
        elif channels is not None and g.lamp not in channels:
            missing = f"lamp {g.lamp!r}, which has no channel in lamps.channels any more"
        elif it.heliostat_id not in heliostats:
            missing = f"heliostat {it.heliostat_id!r}, no longer in heliostats"
        elif g.target is not None and g.target not in targets:
            missing = f"target {g.target!r}, no longer in targets"
        else:
            continue
        raise InputError(f"{where} {missing}; put it back to resume that night")


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
               targets: tuple[str, ...] | None = None, cov: np.ndarray | None = None) -> list[Geometry]:
    """Every geometry of the module docstring's step 1 for one heliostat, on ``targets``
    (default: every target of ``calibration.targets``), measurable with covariance ``cov``
    (default: none, the spot's size alone decides)."""
    geo = FieldGeometry(cfg, np.empty((0, 3)), aim_points)
    cov = np.zeros((len(model.values),) * 2) if cov is None else cov
    out = []
    for tid in targets or cfg.calibration.parallel_targets():
        c = evaluate(geo, heliostat_id, model, cov, tid)
        out += _geometries(c, tid)
    return out


def _geometries(c: Candidates, target: str) -> list[Geometry]:
    return [Geometry(lamp, tuple(float(v) for v in p), cell, (int(st[0]), int(st[1])), target)
            for lamp, p, cell, st in zip(c.lamps, c.points, c.cells, c.steps, strict=True)]


def planner_sun(cfg: PlantConfig) -> np.ndarray:
    """The sun directions the planner scores against: ``planner.sun_positions`` spread evenly
    over the yearly evaluation path (:func:`controller.calibration.night.daytime.sun_path`)."""
    d = sun_path(cfg.site).directions
    n = min(len(d), cfg.calibration.planner.sun_positions)
    return d[np.linspace(0, len(d) - 1, n).round().astype(int)]


def plan_heliostat(cfg: PlantConfig, heliostat_id: str, record: ModelRecord | None, night: str,
                   sun_dirs: np.ndarray, *, strategy: str = "design", offset: int = 0,
                   targets: tuple[str, ...] | None = None) -> list[PlanItem]:
    """Tonight's measurements of one heliostat (module docstring) on ``targets`` (default:
    all). ``strategy`` ``design`` (by expected gain) or ``round-robin`` (:func:`round_robin`,
    starting at candidate ``offset``)."""
    geo = FieldGeometry(cfg, sun_dirs, aim_points)
    return assess(geo, heliostat_id, record, night, strategy, offset, targets)[0]


def assess(geo: FieldGeometry, heliostat_id: str, record: ModelRecord | None, night: str, strategy: str,
           offset: int, targets: tuple[str, ...] | None) -> tuple[list[PlanItem], Unmeasurable | None]:
    """One planning decision: the items of :func:`plan_heliostat` and, when the heliostat has no
    measurable geometry tonight, why."""
    return assess_many(geo, [(heliostat_id, record, night, strategy, offset, targets, frozenset())])[0]


BATCH = 64  # heliostats whose candidates are evaluated together


def assess_many(geo: FieldGeometry, tasks: list[tuple]) -> list[tuple[list[PlanItem], Unmeasurable | None]]:
    """:func:`assess` for each ``(heliostat id, record, night, strategy, offset, targets,
    flagged)`` of ``tasks`` (``flagged``: the heliostat's geometries not to plan, as
    :func:`geometry_key` s): the candidates of :data:`BATCH` heliostats at a time
    (:func:`controller.calibration.night.candidates.evaluate_many`), then each heliostat's picks."""
    cal = geo.cfg.calibration
    out = []
    for start in range(0, len(tasks), BATCH):
        part = tasks[start:start + BATCH]
        for _, _, _, strategy, *_ in part:
            if strategy not in ("design", "round-robin"):
                raise ValueError(f"unknown planning strategy {strategy!r}")
        mc = {hid: model_covariance(rec, cal.model) for hid, rec, *_ in part}
        jobs = [(hid, *mc[hid], tid) for hid, _, _, _, _, targets, _ in part
                for tid in targets or cal.parallel_targets()]
        found = iter(evaluate_many(geo, jobs))
        for hid, _, night, strategy, offset, targets, flagged in part:
            tids = targets or cal.parallel_targets()
            out.append(_decide(geo, hid, mc[hid][1], [(tid, next(found)) for tid in tids], night, strategy,
                               offset, flagged))
    return out


def geometry_key(g: Geometry, calibration_target: str) -> tuple[str, str, tuple[int, int]]:
    """A geometry as the failures of nights name it: (lamp, target, aim grid cell)."""
    return g.lamp, g.target or calibration_target, tuple(g.cell)


def _decide(geo: FieldGeometry, heliostat_id: str, cov: np.ndarray, found: list[tuple[str, Candidates]],
            night: str, strategy: str, offset: int,
            flagged: frozenset = frozenset()) -> tuple[list[PlanItem], Unmeasurable | None]:
    """The picks of one heliostat among its measurable candidates that are not ``flagged``
    (module docstring, steps 2-3)."""
    cal = geo.cfg.calibration
    m = found[0][1].m
    v = float(np.sum(cov * m))
    predicted = 1e3 * math.sqrt(v) if math.isfinite(v) else float("inf")
    n = cal.planner.check_geometries if predicted <= cal.tolerance_mrad else cal.planner.geometries_per_night
    geos = [g for tid, c in found for g in _geometries(c, tid)]
    keep = [i for i, g in enumerate(geos) if geometry_key(g, cal.target) not in flagged
            and (g.lamp, None, None) not in flagged]  # the whole lamp flagged
    if n == 0:
        return [], None
    if not keep:
        why = "; ".join(c.why for _, c in found if c.why) if not geos else \
            f"its {len(geos)} measurable geometries are flagged (each failed on two nights)"
        return [], Unmeasurable(heliostat_id, why, predicted)
    hs = np.concatenate([c.h for _, c in found])[keep]
    geos = [geos[i] for i in keep]
    noise = cal.model.noise_mrad * 1e-3
    if strategy == "round-robin":
        picks, _ = fixed_design(cov, hs, np.empty(0), noise, round_robin(len(geos), n, offset), weight=m)
    else:
        picks, _ = greedy_design(cov, hs, np.empty(0), noise, n, weight=m)
    return [PlanItem(heliostat_id, night, geos[p.index], rank, p.gain, p.rms_before_mrad, p.rms_after_mrad,
                     strategy) for rank, p in enumerate(picks, start=1)], None


def round_robin(count: int, n: int, offset: int) -> list[int]:
    """``n`` candidate indices of ``count`` taken in their fixed order from ``offset`` on
    (wrapping): the schedule without a model of what each measurement is worth."""
    return [(offset + i) % count for i in range(min(n, count))]


def plan_night(cfg: PlantConfig, models: dict[str, ModelRecord | None], night: str, *,
               strategy: str = "design", night_index: int = 0, workers: int | None = None) -> list[PlanItem]:
    """Tonight's plan for the heliostats in ``models`` (id -> latest model or None): the items
    of :func:`plan_field`."""
    return plan_field(cfg, models, night, strategy=strategy, night_index=night_index, workers=workers).items


def plan_field(cfg: PlantConfig, models: dict[str, ModelRecord | None], night: str, *,
               strategy: str = "design", night_index: int = 0, workers: int | None = None,
               flagged: dict[str, frozenset] | None = None) -> NightPlan:
    """Tonight's plan for the heliostats in ``models`` (id -> latest model or None). The queue
    is distributed over ``calibration.targets`` (which run in parallel): heliostat i takes
    tonight target (i + night_index) mod n, so each target gets its share and each heliostat
    another target the next night. Only target time couples the heliostats, so each is
    planned on its own: in ``workers`` processes (:mod:`controller.calibration.night.workers`;
    default one per core for a large field), with the same result as one at a time.
    ``flagged``: per heliostat, the geometries (:func:`geometry_key`) not to plan again (each
    failed on two nights, docs/nights.md)."""
    targets = cfg.calibration.parallel_targets()
    per = cfg.calibration.planner.geometries_per_night
    flagged = flagged or {}
    tasks = [(hid, rec, night, strategy, night_index * per, (targets[(i + night_index) % len(targets)],),
              flagged.get(hid, frozenset())) for i, (hid, rec) in enumerate(models.items())]
    t0 = time.perf_counter()
    done = map_chunks(_plan_chunk, tasks, workers=workers, setup=_setup, setup_args=(cfg,))
    items = [it for its, _ in done for it in its]
    return NightPlan(items, [u for _, u in done if u is not None], len(tasks), time.perf_counter() - t0)


def _setup(cfg: PlantConfig) -> FieldGeometry:
    return FieldGeometry(cfg, planner_sun(cfg), aim_points)


def _plan_chunk(geo: FieldGeometry, tasks: list[tuple]) -> list[tuple[list[PlanItem], Unmeasurable | None]]:
    return assess_many(geo, tasks)
