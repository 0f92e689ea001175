"""The simulated plant, wired in one place: every ``--simulate`` (``heliocal demo``,
``campaign run|night``, ``console``, ``commission``) and ``heliocal report weighting`` ask this
module, the only command module outside ``heliocal sim`` that imports :mod:`simplant` (lazily,
in the simulation path). It builds the simulated field (:func:`simulated_field`), runs the
product's campaign and planned nights on it, scored against the plant's truth, and is the
public entry point benchmarks and tests use for the same.

Nothing here runs a campaign or a night of its own: ``campaign run --simulate`` is the
product's :class:`controller.calibration.campaign.runner.Campaign` and ``campaign night --simulate``
its :class:`controller.calibration.night.planned.PlannedNight`, each on the simulated
:class:`controller.calibration.campaign.field.Field` (:func:`simulated_field`),
each its own plant session whose night index is the number of nights recorded in the
database (the calibration campaign is night 0, the k-th planned night is night k: the plant's
drift and repeatability draws follow). What only the simulator knows — the true error at each
measurement (``sim_truth``), the beam-safety monitor, the true daytime error — is added by
its observers and scoring (``simplant.harness``, ``simplant.daytime``).
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from controller.calibration.campaign.field import Field, PanelLamps
from controller.calibration.campaign.outcome import CampaignResult
from controller.calibration.campaign.runner import Campaign, CampaignOptions
from controller.calibration.night.daytime import PredictedDaytime, predicted_daytime, sun_path
from controller.calibration.night.planned import NightSummary, PlannedNight, calibration_night, tonight
from controller.commands.field import FieldSession, open_store, plant_records
from controller.config import PlantConfig, config_sha256
from controller.devices.factory import LinkPool
from controller.devices.plant_time import PlantTime
from controller.storage.db import CampaignStore
from controller.storage.images import ImageArchive
from controller.storage.nights import NightBook

BUILD = object()  # simulated_field(library=BUILD): the simulated plant's own error library


def simulation_settings(**settings):
    """The simulated plant's settings (:class:`simplant.settings.SimulationSettings`: seed, clock
    speedup, hidden errors, ...)."""
    from simplant.settings import SimulationSettings

    return SimulationSettings(**settings)


@contextmanager
def run_directory(given: str | None, prefix: str) -> Iterator[Path]:
    """The simulated plant's run directory (its ptys and files): ``given`` (``--run-dir``, kept),
    else a temporary one removed when the command ends (one per run of a command, each left in
    the temporary folder before 2026-11-30)."""
    if given:
        yield Path(given)
        return
    import tempfile

    with tempfile.TemporaryDirectory(prefix=prefix) as tmp:
        yield Path(tmp)


def field_selection(cfg: PlantConfig, n: int) -> list[str]:
    """The ``n`` heliostats ``heliocal demo`` calibrates (:func:`simplant.plant.field_selection`)."""
    from simplant.plant import field_selection as select

    return select(cfg, n)


def sim_dir(db: Path) -> Path:
    """Where ``--simulate`` keeps the simulated plant's files (ptys, library, frames) for ``db``:
    shared by ``campaign run`` and every ``campaign night`` on it."""
    return db.parent / f"{db.stem}-sim"


def simulated_plant(config_path: str, run_dir: Path, ids: list[str], *, seed: int):
    """The simulated plant of ``config_path`` with heliostats ``ids`` (not started; a context
    manager), for ``heliocal commission --simulate``."""
    from simplant.plant import SimulatedPlant, load_config_data

    return SimulatedPlant(load_config_data(config_path), run_dir, heliostat_ids=ids,
                          settings=simulation_settings(seed=seed), source=config_path)


def weighting_study():
    """The simulator's HDR weighting study (:mod:`simplant.studies.weighting`, it needs the
    simulator's noise-free irradiance) for ``heliocal report weighting``."""
    from simplant.studies import weighting

    return weighting


@contextmanager
def simulated_field(cfg: PlantConfig, config_path: str, store: CampaignStore, out: Path, ids: list[str],
                    settings, *, night: int, library_dir: Path | None = None, clock_start: float = 0.0,
                    progress=None, library: Any = BUILD) -> Iterator[FieldSession]:
    """The embedded simulated plant in ``out`` on night ``night`` (its drift and repeatability
    draws), its heliostats ``ids``. ``library``: the error library, or :data:`BUILD` (the
    default): the simulated plant's own, built once into ``library_dir`` (default ``out``) and
    reused."""
    from simplant.harness import demo_library
    from simplant.plant import SimulatedPlant, load_config_data

    out.mkdir(parents=True, exist_ok=True)
    lib = demo_library(cfg, config_path, library_dir or out, ids, settings.seed, progress) \
        if library is BUILD else library
    plant = SimulatedPlant(load_config_data(config_path), out / "plant", heliostat_ids=ids, settings=settings,
                           source=str(config_path), clock_start=clock_start)
    plant.set_night(night)
    with plant, LinkPool(timeout_s=0.5, retries=2) as pool:
        plant.start()
        f = plant_field(plant, config_path, store, pool, library=lib, images=ImageArchive(out / "images"))
        try:
            yield FieldSession(f, NightBook(store), plant)
        finally:
            f.lamps.close()


def plant_field(plant, config_path: str | Path, store, pool, *, library=None, images=None) -> Field:
    """The :class:`Field` of a started simulated plant (``plant.start()`` done): its rewritten
    configuration and links through ``pool``, its cameras, its lamp panel over Modbus TCP, its
    clock. Close ``field.lamps`` when done."""
    clock = plant.clock
    time = PlantTime(now=clock, sleep=clock.sleep, utc=plant.utc, computing=clock.realtime)
    s = plant.settings
    meta = {"plant": "simulated", "seed": plant.seed, "clock_speedup": s.clock_speedup}
    lamps = PanelLamps.open(plant.config.lamps, time)
    field = Field(plant.config, str(config_path), config_sha256(config_path), store, pool, plant.cameras,
                  time, lamps, images, library, meta=meta, label="simulated plant")
    return plant_records(field)




@dataclass(frozen=True)
class NightReport:
    """A simulated planned night: the product's :class:`NightSummary` and the field's true
    daytime error after it (open loop, sun path, against the plant's truth of that night)."""

    summary: NightSummary
    daytime: Any  # simplant.daytime.DaytimeError
    predicted: PredictedDaytime

    @property
    def night(self) -> int:
        return self.summary.night

    @property
    def measured(self) -> int:
        return self.summary.measured

    @property
    def planned(self) -> int:
        return self.summary.planned

    def to_json(self) -> dict:
        s = self.summary
        return {"night": s.night, "name": s.name, "planned": s.planned, "measured": s.measured,
                "daytime_error_mrad": self.daytime.to_json(),
                "daytime_error_predicted_mrad": self.predicted.to_json(),
                "lamp_changes": s.lamp_changes, "lamps": s.lamps, "status": s.status}


@dataclass
class SimulatedRun:
    """A calibration campaign and its planned nights on the simulated plant, with the truth."""

    result: CampaignResult
    truth: dict
    safety: dict  # the beam-safety monitor over every session (samples, violations, max beams)
    settings: Any
    db: Path
    out: Path
    daytime: Any  # open loop over the sun path, latest models, plant truth of the last night
    daytime_uncalibrated: Any
    predicted: PredictedDaytime
    nights: list[NightReport]
    on_target: dict[str, list[tuple[float, float, str]]] = field(default_factory=dict)

    @property
    def exit_code(self) -> int:
        """The worst outcome of the calibration campaign and every planned night (docs/cli.md):
        1 one aborted, 130 one interrupted, 3 one partial, 0 all finished."""
        codes = {self.result.exit_code, *(r.summary.exit_code for r in self.nights)}
        return next((c for c in (1, 130, 3) if c in codes), 0)


def _merge_safety(plant, into: dict | None, on_target: dict | None) -> None:
    """Add a plant session's beam-safety monitor (counts; spans with a beam on each target) to
    those of the sessions before it."""
    r = plant.safety.report()
    if into is not None:
        into["samples"] = into.get("samples", 0) + r["samples"]
        into["violations"] = into.get("violations", 0) + r["violations"]
        into["max_beams_on_target"] = max(into.get("max_beams_on_target", 0), r["max_beams_on_target"])
        into["misassigned"] = into.get("misassigned", 0) + plant.spot_truth.misassigned_count
        into["centroid_errors_m"] = into.get("centroid_errors_m", []) + plant.spot_truth.errors_m
    if on_target is not None:
        for tid, spans in plant.safety.intervals.items():
            on_target.setdefault(tid, []).extend(spans)


def calibrate(cfg: PlantConfig, config_path: str, store: CampaignStore, out: Path, ids: list[str],
              settings, name: str, *, sequential: bool = False, observers=(), progress=None,
              library_dir: Path | None = None, safety: dict | None = None,
              on_target: dict | None = None) -> CampaignResult:
    """``campaign run --simulate``: campaign ``name`` (night 0 of a fresh database) on the
    simulated plant, with the plant's truth recorded per run."""
    from simplant.harness import TruthRecorder

    book = NightBook(store)
    with simulated_field(cfg, config_path, store, out, ids, settings, night=book.index_for(name),
                         library_dir=library_dir, clock_start=store.last_end_s(name) or 0.0,
                         progress=progress) as fs:
        opts = CampaignOptions(name=name, pipeline_depth=1 if sequential else None)
        campaign = Campaign(fs.field, opts, heliostat_ids=ids,
                            observers=[TruthRecorder(fs.plant, store.path), *observers])
        result = calibration_night(book, campaign)
        _merge_safety(fs.plant, safety, on_target)
    return result


def planned_night(cfg: PlantConfig, config_path: str, store: CampaignStore, out: Path, ids: list[str],
                  settings, base: str, *, observers=(), progress=None, library_dir: Path | None = None,
                  strategy: str = "design", safety: dict | None = None,
                  on_target: dict | None = None) -> NightReport:
    """``campaign night --simulate``: tonight's planned night (or the unfinished one) on the
    simulated plant of that night, scored against its truth."""
    from simplant.daytime import daytime_error
    from simplant.harness import TruthRecorder

    book = NightBook(store)
    name, index = tonight(book, base)
    with simulated_field(cfg, config_path, store, out, ids, settings, night=index, library_dir=library_dir,
                         clock_start=book.last_end_s(name) or 0.0, progress=progress) as fs:
        night = PlannedNight(fs.field, book, name, index, heliostat_ids=ids, strategy=strategy,
                             observers=[TruthRecorder(fs.plant, store.path), *observers], progress=progress)
        summary = night.run()
        models = {hid: store.latest_model(hid) for hid in ids}
        path = sun_path(cfg.site)
        report = NightReport(summary, daytime_error(fs.plant, cfg, models, path),
                             predicted_daytime(cfg, models, path))
        book.add_to_summary(name, {"truth": {"daytime_error_mrad": report.daytime.to_json()}})
        _merge_safety(fs.plant, safety, on_target)
    if progress is not None:
        progress(f"{name}: field daytime error now {report.predicted.rms:.2f} mrad RMS predicted, "
                 f"{report.daytime.rms:.2f} true (plant truth)")
    return report


def simulated_run(cfg: PlantConfig, config_path: str, out: Path, db: Path, ids: list[str], *, settings,
                  name: str, sequential: bool = False, library_dir: Path | None = None, observers=(),
                  progress=None, nights: int = 0) -> SimulatedRun:
    """Calibration campaign ``name`` then ``nights`` planned nights, each its own plant session
    as separate ``campaign run|night --simulate`` processes would be, and the field's daytime
    error against the plant's truth of the last night."""
    from simplant.daytime import daytime_error
    from simplant.harness import read_truth
    from simplant.plant import SimulatedPlant, load_config_data

    safety: dict = {}
    on_target: dict = {}
    store = open_store(db)
    try:
        result = calibrate(cfg, config_path, store, out, ids, settings, name, sequential=sequential,
                           observers=observers, progress=progress, library_dir=library_dir, safety=safety,
                           on_target=on_target)
        reports = []
        for _ in range(nights if result.status in ("finished", "partial") else 0):
            reports.append(planned_night(cfg, config_path, store, out, ids, settings, name, progress=progress,
                                         library_dir=library_dir, safety=safety, on_target=on_target))
        models = {hid: store.latest_model(hid) for hid in ids}
        path = sun_path(cfg.site)
        truth = SimulatedPlant(load_config_data(config_path), out / "plant", heliostat_ids=ids,
                               settings=settings, source=str(config_path))
        truth.set_night(NightBook(store).next_index() - 1)
        daytime = reports[-1].daytime if reports else daytime_error(truth, cfg, models, path)
        predicted = reports[-1].predicted if reports else predicted_daytime(cfg, models, path)
        uncalibrated = daytime_error(truth, cfg, dict.fromkeys(ids), path)
        store.update_meta(result.campaign_id, {"beam_safety_last_session": safety,
                                               "daytime_error_mrad": daytime.to_json(),
                                               "daytime_error_predicted_mrad": predicted.to_json(),
                                               "daytime_error_uncalibrated_mrad": uncalibrated.to_json(),
                                               "nights": [r.to_json() for r in reports]})
    finally:
        store.close()
    return SimulatedRun(result, read_truth(db, result.campaign_id), safety, settings, db, out, daytime,
                        uncalibrated, predicted, reports, on_target)


def simulated_campaign(cfg, config_path: str, out: Path, db: Path, ids: list[str], settings, name: str, *,
                       sequential: bool = False, quiet: bool = True, library_dir: Path | None = None,
                       nights: int = 0):
    """The calibration campaign (``campaign run --simulate``) and ``nights`` planned nights
    (``campaign night --simulate``) on the simulated plant, and the morning report with the
    plant's truth; returns (summary dict, :class:`SimulatedRun`)."""
    from controller.commands._progress import TerminalProgress
    from controller.reports.campaign import write_report
    from controller.reports.summary import coarse_summary, summarize
    from controller.storage.db import open_existing

    sim = simulated_run(cfg, config_path, out, db, ids, settings=settings, name=name, sequential=sequential,
                        library_dir=library_dir, observers=[] if quiet else [TerminalProgress()],
                        progress=None if quiet else (lambda text: print(text, file=sys.stderr)),
                        nights=nights)
    with open_existing(db) as store:
        report = write_report(store, out / "report", sim.result.campaign_id, truth=sim.truth)
        summary = summarize(store, sim.result.campaign_id, truth=sim.truth)
        summary["coarse_correction"] = coarse_summary(store, sim.result.campaign_id,
                                                      cfg.calibration.coarse_correction)
    summary["daytime_error_mrad"] = sim.daytime.to_json()
    summary["daytime_error_predicted_mrad"] = sim.predicted.to_json()
    summary["daytime_error_uncalibrated_mrad"] = sim.daytime_uncalibrated.to_json()
    summary["nights"] = [r.to_json() for r in sim.nights]
    summary["db"] = str(db)
    summary["report"] = str(report)
    return summary, sim


def plant_crf_config(work: Path, *, small: bool = True) -> Path:
    """The packaged demo plant as ``work/plant.yaml``, its cameras 256×192 when ``small``, and
    the simulated sensors' responses (the plant writes them into ``work/plant0``) named as the
    controller's CRF files, as a sphere calibration would hand them over: the configuration a
    recorded archive is reprocessed with (``tests/calibration/reprocess``, ``bench_reprocess``)."""
    import yaml

    from controller.commands.common import PACKAGED_CONFIG
    from simplant.plant import SimulatedPlant
    from simplant.settings import SimulationSettings

    data = yaml.safe_load(Path(PACKAGED_CONFIG).read_text())
    if small:
        for cam in [data["camera"]] + [t["camera"] for t in data["targets"] if t.get("camera")]:
            cam["width_px"], cam["height_px"] = 256, 192
            if cam.get("registration"):
                cam["registration"]["focal_px"] *= 256 / 1024
    with SimulatedPlant(data, work / "plant0", settings=SimulationSettings(seed=0)) as plant:
        plant.start()
    data["camera"]["crf_file"] = str(work / "plant0" / "crf.yaml")
    for t in data["targets"]:
        if t.get("camera"):
            t["camera"]["crf_file"] = str(work / "plant0" / f"crf-{t['id']}.yaml")
    config = work / "plant.yaml"
    config.write_text(yaml.safe_dump(data, sort_keys=False))
    return config
