"""Runs the product's campaign against the simulated plant and keeps the plant's truth.

The controller records what it measured (``controller.storage``); this harness observes the
campaign (:class:`controller.calibration.runner.CampaignObserver`) and writes what only the
simulator knows into its own table ``sim_truth`` of the same database file: per recorded run,
the injected error case and the true reflected-beam error at the first and the last
measurement. Reports written by the simulation commands read it back (:func:`read_truth`).
"""

from __future__ import annotations

import json
import sqlite3
import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from controller.calibration.daytime import PredictedDaytime, predicted_daytime, sun_path
from controller.calibration.lamp_change import LampChange, LampChanger, Standby, night_drives
from controller.calibration.nights import Pass, run_night
from controller.calibration.planner import plan_night
from controller.calibration.records import MeasurementRecord, RunRecord
from controller.calibration.runner import Campaign, CampaignObserver, CampaignOptions, CampaignResult
from controller.config import PlantConfig, config_sha256
from controller.devices.factory import LinkPool
from controller.geometry.vectors import unit
from controller.recognition.library import Library
from controller.reports.summary import ReferenceTruth
from controller.storage.db import CampaignStore
from controller.storage.images import ImageArchive
from controller.storage.plans import load_plan, record_plan
from simplant.daytime import DaytimeError, daytime_error
from simplant.plant import SimulatedPlant, load_config_data
from simplant.reference_set import write_reference_set
from simplant.settings import SimulationSettings

_SCHEMA = """
CREATE TABLE IF NOT EXISTS sim_truth (
    run_id INTEGER PRIMARY KEY,
    campaign_id INTEGER NOT NULL,
    heliostat_id TEXT NOT NULL,
    truth_label TEXT NOT NULL,
    true_error_before_mrad REAL,
    true_error_after_mrad REAL
)
"""


class TruthRecorder(CampaignObserver):
    """Reads the plant's true pointing error at every measurement and stores, per recorded
    run, the first and last one with the injected case (own connection, own transaction)."""

    def __init__(self, plant: SimulatedPlant, db_path: str | Path) -> None:
        self.plant = plant
        self.db_path = str(db_path)
        self._errors: dict[str, list[float]] = {}
        self._lock = threading.Lock()
        with sqlite3.connect(self.db_path) as db:
            db.execute(_SCHEMA)

    def measured(self, heliostat_id: str, measurement: MeasurementRecord) -> None:
        err = self.plant.true_error_mrad(heliostat_id)
        with self._lock:
            self._errors.setdefault(heliostat_id, []).append(err)

    def run_recorded(self, campaign_id: int, run: RunRecord) -> None:
        with self._lock:
            errs = self._errors.pop(run.heliostat_id, [])
        with sqlite3.connect(self.db_path, timeout=10.0) as db:
            db.execute("INSERT OR REPLACE INTO sim_truth VALUES (?,?,?,?,?,?)",
                       (run.id, campaign_id, run.heliostat_id, self.plant.truth_label(run.heliostat_id),
                        errs[0] if errs else None, errs[-1] if errs else None))


def read_truth(db_path: str | Path, campaign_id: int) -> dict[str, ReferenceTruth]:
    """The simulated truth of every recorded run of a campaign (heliostat id -> truth)."""
    with sqlite3.connect(f"file:{db_path}?mode=ro", uri=True) as db:
        if db.execute("SELECT 1 FROM sqlite_master WHERE name='sim_truth'").fetchone() is None:
            return {}
        rows = db.execute("SELECT heliostat_id, truth_label, true_error_before_mrad, true_error_after_mrad "
                          "FROM sim_truth WHERE campaign_id=?", (campaign_id,)).fetchall()
    return {hid: ReferenceTruth(label, before, after) for hid, label, before, after in rows}


_BUDGET_SCHEMA = """
CREATE TABLE IF NOT EXISTS sim_budget (
    id INTEGER PRIMARY KEY,
    heliostat_id TEXT NOT NULL,
    night INTEGER NOT NULL,
    az_steps INTEGER NOT NULL,
    el_steps INTEGER NOT NULL,
    vectors TEXT NOT NULL
)
"""


class MeasurementBudget(CampaignObserver):
    """Error budget of every measurement (simulation only, the plant knows both sides).

    Stores, per measurement, the lamp (``lamp_enu``), the true mirror centre (``center_enu``)
    and the normals whose angles split the measured normal's error
    against ``true_normal_at`` at the commanded steps (what the model must learn):
    ``ref`` that normal; ``rods`` the beam normal at the rods' true positions (backlash);
    ``pose`` the same with the move's repeatability error (rocking gear averaged);
    ``energy`` the bisector of the lamp and the noise-free energy centroid of the traced spot
    (the spot's geometry-dependent shift against ``pose``); ``measured`` the bisector of the
    lamp and the camera's centroid (centroid/pixel error against ``energy``). Every bisector is
    taken from the true mirror centre, so position errors do not enter. Drift is the change of
    ``ref`` between nights (:func:`read_budget` leaves that to its caller)."""

    def __init__(self, plant: SimulatedPlant, db_path: str | Path) -> None:
        self.plant = plant
        self.db_path = str(db_path)
        with sqlite3.connect(self.db_path) as db:
            db.execute(_BUDGET_SCHEMA)

    def measured(self, heliostat_id: str, measurement: MeasurementRecord) -> None:
        from simplant.grids import camera_grid
        from simplant.optics import TargetGrid, render_spot

        p, hh = self.plant, self.plant.hidden[heliostat_id]
        cmd = (float(measurement.az_steps), float(measurement.el_steps))
        rods = hh.controller.output_steps()
        lamp = np.asarray(p.lamp().position_enu_m, float)
        pos = hh.truth.mirror_center(*rods, night=p.night)
        s = unit(lamp - pos)
        with p.clock.frozen():
            normals = p.beam_normals(heliostat_id)
            pose = hh.beam_normal(unit(np.mean(normals, axis=0)))
            beam = 2.0 * (s @ pose) * pose - s
            base = camera_grid(p.cfg)
            hit = pos + float(base.normal @ (base.center - pos)) / float(base.normal @ beam) * beam
            grid = TargetGrid(hit, base.normal, base.u_axis, base.v_axis, 12.0, 12.0, (64, 64))
            diameter = float(p.lamp().diameter_m) / float(np.linalg.norm(lamp - pos))
            img = sum(render_spot(pos, nn, lamp, diameter, hh.mirror, grid, rng=np.random.default_rng(1),
                                  n_rays=100_000 // len(normals)) for nn in normals)
        yy, xx = np.mgrid[0:64, 0:64]
        tot = float(img.sum())
        energy = grid.pixel_to_enu(float((img * xx).sum() / tot), float((img * yy).sum() / tot))
        out = {"ref": p.true_normal_at(heliostat_id, *cmd),
               "rods": hh.beam_normal(hh.truth.normal(*rods, night=p.night)),
               "pose": pose, "energy": unit(s + unit(energy - pos)), "lamp_enu": lamp, "center_enu": pos}
        if measurement.centroid_enu is not None:
            out["measured"] = unit(s + unit(np.asarray(measurement.centroid_enu, float) - pos))
        with sqlite3.connect(self.db_path, timeout=10.0) as db:
            db.execute("INSERT INTO sim_budget (heliostat_id, night, az_steps, el_steps, vectors) "
                       "VALUES (?,?,?,?,?)",
                       (heliostat_id, p.night, measurement.az_steps, measurement.el_steps,
                        json.dumps({k: [float(x) for x in v] for k, v in out.items()})))


def read_budget(db_path: str | Path) -> list[dict]:
    """Rows of ``sim_budget`` (:class:`MeasurementBudget`): heliostat, night, steps, vectors."""
    with sqlite3.connect(f"file:{db_path}?mode=ro", uri=True) as db:
        rows = db.execute("SELECT heliostat_id, night, az_steps, el_steps, vectors FROM sim_budget "
                          "ORDER BY id").fetchall()
    return [{"heliostat": h, "night": k, "steps": (az, el),
             "vectors": {n: np.asarray(v) for n, v in json.loads(js).items()}} for h, k, az, el, js in rows]


FIELD_FACTOR = 1.5


def widen_unknown_for_field(lib: Library, factor: float = FIELD_FACTOR) -> Library:
    """Raise each entry's ``unknown`` threshold to ``factor`` x the largest distance to the
    same case's entries from the other reference heliostats.

    The library's own calibration covers framing and noise of one view; across a field the
    same error looks different from every heliostat (distance, incidence angle), and the
    references measure exactly that spread. Thresholds are only ever raised."""
    x = lib.matrix() / lib.scale
    labels = np.array(lib.labels)
    for i, e in enumerate(lib.entries):
        same = (labels == e.label) & (np.arange(len(labels)) != i)
        if same.any():
            spread = float(np.max(np.linalg.norm(x[same] - x[i], axis=1)))
            e.unknown_distance = max(float(e.unknown_distance), factor * spread)
    return lib


def demo_library(cfg: PlantConfig, config_path: str, out: Path, ids: list[str], seed: int,
                 progress=None) -> Library:
    """The error library of a simulated run: the error set's cases rendered through the plant's
    own camera for three reference heliostats across the field (first, middle, last of the
    run), built once into ``out/library.yaml`` and then reused. ``progress(text)`` is told
    when the (slow) build starts."""
    from controller.recognition.library_io import build_library_from_manifest, load_library, save_library

    path = out / "library.yaml"
    if path.is_file():
        return load_library(path)
    refs = list(dict.fromkeys([ids[0], ids[len(ids) // 2], ids[-1]]))
    if progress is not None:
        progress(f"building the error library: 6 error-set cases x {len(refs)} reference heliostats ...")
    manifest = write_reference_set(load_config_data(config_path), out / "errorset", refs, seed=seed,
                                   source=str(config_path))
    lib = widen_unknown_for_field(build_library_from_manifest(manifest, kind="log-hu",
                                                              threshold=cfg.calibration.threshold))
    save_library(lib, path)
    return lib


class LampSwitch(CampaignObserver):
    """Lights the lamp (and the fiducial lamps) a campaign asks for in the simulated plant (a
    lamp controller's job)."""

    def __init__(self, plant: SimulatedPlant, target: str | None = None) -> None:
        self.plant = plant
        self.target = target

    def light_source_needed(self, source_id: str) -> None:
        self.plant.set_light(source_id)

    def fiducial_lamps(self, on: bool) -> None:
        self.plant.set_fiducials(on, self.target)


@dataclass(frozen=True)
class NightReport:
    """After one simulated night: its name, the measurements planned and taken, and the
    field's daytime error (true, against the plant, and predicted from the models' σ)."""

    night: int
    name: str
    planned: int
    measured: int
    daytime: DaytimeError
    predicted: PredictedDaytime
    lamp_changes: list[LampChange] = field(default_factory=list)  # in the dark, before each lamp

    def to_json(self) -> dict:
        return {"night": self.night, "name": self.name, "planned": self.planned, "measured": self.measured,
                "daytime_error_mrad": self.daytime.to_json(),
                "daytime_error_predicted_mrad": self.predicted.to_json(),
                "lamp_changes": [c.to_json() for c in self.lamp_changes]}


@dataclass
class SimulatedRun:
    """What :func:`run_simulated` hands back: the campaign result, the plant truth per
    heliostat, the beam-safety monitor's report and where the files went."""

    result: CampaignResult
    truth: dict[str, ReferenceTruth]
    safety: dict
    settings: SimulationSettings
    db: Path
    out: Path
    daytime: DaytimeError  # open loop over the sun path, latest models, against the plant truth
    daytime_uncalibrated: DaytimeError  # the same with the nominal kinematics
    predicted: PredictedDaytime  # what the models' own covariance predicts for ``daytime``
    nights: list[NightReport]  # after each planned night (empty with nights=0)
    on_target: dict[str, list[tuple[float, float, str]]] = field(default_factory=dict)  # per target:
    # the plant-clock spans (start, end, heliostat) with one beam on it (the safety monitor's truth)


def run_simulated(cfg: PlantConfig, config_path: str, out: Path, db_path: Path, ids: list[str], *,
                  settings: SimulationSettings, name: str, sequential: bool = False,
                  library_dir: Path | None = None, observers=(), progress=None, nights: int = 0,
                  strategy: str = "design", budget: bool = False) -> SimulatedRun:
    """Start the simulated plant in ``out``, run (or resume) campaign ``name`` into ``db_path``
    through the real drivers — the closed-loop calibration at the calibration lamp — then
    ``nights`` planned nights (:mod:`controller.calibration.nights`, planner ``strategy``), and
    return what happened with the plant's truth. ``progress(text)`` hears of each pass."""
    store = CampaignStore(db_path)
    try:
        # Refuse a database in use before any slow work (the error set takes a while to render).
        store.campaign_lock.acquire()
        out.mkdir(parents=True, exist_ok=True)
        lib = demo_library(cfg, config_path, library_dir or out, ids, settings.seed, progress)
        # The plant timeline continues where the recorded work ended, so a resumed campaign's
        # plant-time span covers exactly the recorded work.
        start = store.last_end_s(name) or 0.0
        plant = SimulatedPlant(load_config_data(config_path), out / "plant", heliostat_ids=ids,
                               settings=settings, source=str(config_path), clock_start=start)
        with plant:
            plant_cfg = plant.start()
            cal = cfg.calibration
            opts = CampaignOptions(name=name, pipeline_depth=1 if sequential else cal.pipeline_depth,
                                   settle_s=cal.settle_s)
            truth = TruthRecorder(plant, db_path)
            budgeted = [MeasurementBudget(plant, db_path)] if budget else []
            path = sun_path(cfg.site)
            live: set[Campaign] = set()  # running campaigns, one per target at most
            with LinkPool(timeout_s=0.5, retries=2) as pool:
                def campaign(options: CampaignOptions, hids: list[str], extra=()) -> CampaignResult:
                    tid = options.target or plant_cfg.calibration.target
                    c = Campaign(plant_cfg, config_path, store, pool, plant.cameras[tid],
                                 config_sha256=config_sha256(config_path), heliostat_ids=hids, library=lib,
                                 options=options, images=ImageArchive(out / "images"), clock=plant.clock,
                                 sleep=plant.clock.sleep, compute=plant.clock.realtime, utc=plant.utc,
                                 meta={"plant": "simulated", "seed": settings.seed,
                                       "clock_speedup": settings.clock_speedup},
                                 observers=[LampSwitch(plant, tid), truth, *budgeted, *extra])
                    live.add(c)
                    try:
                        return c.run()
                    finally:
                        live.discard(c)

                def stop_all() -> None:  # Ctrl-C during parallel targets: every campaign parks
                    for c in list(live):
                        c.request_stop()

                result = campaign(opts, ids, observers)
                # A night's lamp changes: lamps off, heliostats safe for the next lamp, then light it.
                changer = LampChanger(plant_cfg, night_drives(plant_cfg, pool), store.latest_model,
                                      plant.lights_out, clock=plant.clock, sleep=plant.clock.sleep,
                                      compute=plant.clock.realtime)
                reports = []
                for k in range(nights if result.status in ("finished", "partial") else 0):
                    plant.set_night(k)
                    night = f"{name}/night-{k + 1}"
                    reports.append(_planned_night(cfg, store, plant, campaign, ids, k, night, strategy, path,
                                                  progress, stop_all, changer))
                plant.set_light(cfg.calibration.light_source)
            safety = plant.safety.report()
            on_target = plant.safety.intervals
        # What the nights were for: open-loop tracking of the sun with each heliostat's latest
        # model, scored against the plant's truth (and, for scale, with no model at all).
        models = {hid: store.latest_model(hid) for hid in ids}
        daytime = reports[-1].daytime if reports else daytime_error(plant, cfg, models, path)
        predicted = reports[-1].predicted if reports else predicted_daytime(cfg, models, path)
        uncalibrated = daytime_error(plant, cfg, dict.fromkeys(ids), path)
        store.update_meta(result.campaign_id, {"beam_safety_last_session": safety,
                                               "daytime_error_mrad": daytime.to_json(),
                                               "daytime_error_predicted_mrad": predicted.to_json(),
                                               "daytime_error_uncalibrated_mrad": uncalibrated.to_json(),
                                               "nights": [r.to_json() for r in reports]})
    finally:
        store.close()
    return SimulatedRun(result, read_truth(db_path, result.campaign_id), safety, settings, db_path, out,
                        daytime, uncalibrated, predicted, reports, on_target)


def _planned_night(cfg: PlantConfig, store: CampaignStore, plant: SimulatedPlant, campaign, ids: list[str],
                   k: int, night: str, strategy: str, path, progress, stop_all,
                   changer: LampChanger) -> NightReport:
    """Plan (or reload the stored plan of) night ``k``, run its passes, score the field."""
    plan = load_plan(store, night)
    if not plan:
        plan = plan_night(cfg, {hid: store.latest_model(hid) for hid in ids}, night, strategy=strategy,
                          night_index=k)
        record_plan(store, plan)
    if progress is not None:
        before = max((i.predicted_before_mrad for i in plan if i.rank == 1), default=float("nan"))
        helios = len({i.heliostat_id for i in plan})
        progress(f"{night}: {len(plan)} geometries planned for {helios} heliostats "
                 f"(worst predicted daytime RMS {before:.2f} mrad)")

    tally_lock = threading.Lock()
    planned = {i.heliostat_id for i in plan}
    tally: dict[str, set[str]] = {"geometries": set(), "heliostats": set()}

    def run_pass(p: Pass) -> CampaignResult:
        if progress is not None:
            progress(f"{p.name}: {len(p.aims)} heliostat(s) under {p.lamp}"
                     + (f" on {p.target}" if p.target else ""))
        r = campaign(CampaignOptions(name=p.name, light_source=p.lamp, aims=p.aims, observe=True,
                                     pipeline_depth=cfg.calibration.pipeline_depth,
                                     settle_s=cfg.calibration.settle_s, target=p.target), list(p.aims))
        if progress is not None:
            # Tonight so far, all targets: what was measured and where the field's predicted
            # daytime error stands (the plant clock stands still: this is the operator's view).
            with tally_lock, plant.clock.frozen():
                done = [run for run in r.runs if run.status == "measured"]
                tally["geometries"] |= {f"{p.name}/{run.heliostat_id}" for run in done}
                tally["heliostats"] |= {run.heliostat_id for run in done}
                now = predicted_daytime(cfg, {hid: store.latest_model(hid) for hid in ids}, path)
                progress(f"{night}: {len(tally['geometries'])}/{len(plan)} geometries, "
                         f"{len(tally['heliostats'])}/{len(planned)} heliostats measured; "
                         f"field predicted daytime RMS {now.rms:.2f} mrad")
        return r

    changes: list[LampChange] = []

    def change_lamp(lamp: str, standbys: dict[str, Standby]):
        done = changer(lamp, standbys)
        changes.append(done)
        if progress is not None:
            progress(f"{night}: {lamp} lit after moving {len(done.parked)} heliostat(s) to its standby "
                     f"and stowing {len(done.stowed)}, in the dark")
        return done

    results = run_night(plan, night, run_pass, stop_all, change_lamp)
    models = {hid: store.latest_model(hid) for hid in ids}
    measured = sum(1 for r in results for run in r.runs if run.status == "measured")
    report = NightReport(k + 1, night, len(plan), measured, daytime_error(plant, cfg, models, path),
                         predicted_daytime(cfg, models, path), changes)
    if progress is not None:
        progress(f"{night}: {measured}/{len(plan)} geometries measured; field daytime error now "
                 f"{report.predicted.rms:.2f} mrad RMS predicted, {report.daytime.rms:.2f} true "
                 "(plant truth)")
    return report
