"""A PAINT folder's calibration records into the field's store (``heliocal import paint``,
docs/import.md).

Each record becomes one measurement of a sun calibration: motor steps (``axis_1`` elevation,
``axis_2`` azimuth), the sun's direction at the record's UTC time (PAINT's ``sun_azimuth`` is
from south, positive east: ours is 180° − it), the focal spot in the plant frame as the beam's
centroid (UTIS's, else HeliOS's) — so the measured mirror normal is the bisector of
heliostat→sun and heliostat→spot, as for every measurement of the store — and the record's
target. PAINT records no aim point: the target's centre stands in for it, and no pointing
error is stored. The measurements of one import are one campaign (``paint-import-<n>``, light
source ``sun``, status finished), a run per heliostat (status ``measured``) holding its new
records in time order; ``imported_records`` ties each to its file (heliostat, record id,
SHA-256), so a re-import adds only new records and refuses a record whose file changed.

Everything is read and checked first; the configuration file (when written) and then every
row go in, the rows in one transaction: a bad file leaves the store as it was.
"""

from __future__ import annotations

import json
import math
import time
from collections import Counter
from dataclasses import asdict, dataclass, field
from datetime import datetime
from pathlib import Path

import numpy as np

from controller.calibration.records import utc_now
from controller.config import PlantConfig, config_sha256, load_config, parse_config
from controller.errors import InputError
from controller.geometry.aiming import aim_normal
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.paint_io import TargetPlane, Towers, read_timestamps, read_towers
from controller.io.files import check_regular, read_bytes
from controller.io.images import write_atomic
from controller.storage.db import CampaignStore
from controller.storage.paint.field_config import field_document
from controller.storage.paint.folder import FolderHeliostat, FolderRecord, read_folder

SOURCE = "paint"


@dataclass
class HeliostatImport:
    """What became of one heliostat's records: found, imported now, imported before, those
    without a time (not imported), those whose spot is HeliOS's (no UTIS), how many lie outside
    the configured soft limits or where the configured stroke leaves the actuator triangle (the
    nominal kinematics has no normal there), and the median angle between the nominal and the
    measured mirror normal (mrad). ``note``: a narrowed or refused axis."""

    records: int
    imported: int = 0
    already_imported: int = 0
    no_time: list[str] = field(default_factory=list)
    helios_only: list[str] = field(default_factory=list)
    outside_soft_limits: int = 0
    outside_triangle: int = 0
    nominal_miss_mrad: float | None = None
    note: str | None = None


@dataclass
class PaintImport:
    """The outcome (the ``import paint --json`` keys)."""

    db: str
    config: str
    config_sha256: str
    config_written: bool
    campaign: str | None
    imported: int
    already_imported: int
    heliostats: dict[str, HeliostatImport]
    refused: dict[str, str]
    seconds: float

    def to_json(self) -> dict:
        return {**asdict(self), "heliostats": {h: asdict(v) for h, v in self.heliostats.items()}}


def config_beside(db: str | Path) -> Path:
    """Where the field configuration of an import without ``--config`` is written: beside the
    database, ``<db name without suffix>.config.yaml``."""
    p = Path(db)
    return p.with_name(f"{p.stem}.config.yaml")


def config_towers(cfg: PlantConfig, path: str) -> Towers:
    """The targets of a configuration as a :class:`Towers`, its frame's origin the site."""
    s = cfg.site
    return Towers((s.latitude_deg, s.longitude_deg, s.elevation_m),
                  {t.id: TargetPlane(t.id, np.asarray(t.center_enu_m, float), np.asarray(t.normal, float),
                                     (t.width_m, t.height_m)) for t in cfg.targets},
                  described_by=path)


def import_paint(folder: str | Path, db: str | Path, *, config: str | None = None,
                 timestamps: str | None = None) -> PaintImport:
    """Import ``folder`` into ``db`` (module docstring); InputError/ConfigError naming the file
    and key on any bad input, with nothing written."""
    t0 = time.perf_counter()
    folder = Path(folder)
    check_regular(db, "database")
    times = read_timestamps(timestamps or folder / "timestamps.json")
    notes: dict[str, str] = {}
    refused: dict[str, str] = {}
    if config is not None:
        cfg_path, cfg, text = Path(config), load_config(config), None
        helios = read_folder(folder, config_towers(cfg, str(config)), times)
        known = {h.id for h in cfg.heliostats}
        for h in helios:
            if h.heliostat_id not in known:
                raise InputError(f"{h.properties_path}: heliostat {h.heliostat_id!r} is not in {config}; add "
                                 "it, or import without --config to write the field's configuration")
    else:
        towers = read_towers(folder / "tower-measurements.json")
        helios = read_folder(folder, towers, times)
        used = Counter(r.record.target.name for h in helios for r in h.records)
        fc = field_document(towers, {h.heliostat_id: (str(h.properties_path), h.properties) for h in helios},
                            used)
        cfg_path, text = config_beside(db), fc.yaml_text()
        refused, notes = fc.refused, fc.notes
        cfg = parse_config(fc.document, str(cfg_path))  # the text's document, as safe_dump wrote it
        _check_replaceable(cfg_path, text)
    report = {h.heliostat_id: _assess(cfg, h, refused, notes) for h in helios}
    store = CampaignStore(db)
    try:
        store.campaign_lock.acquire()  # no campaign writes meanwhile (DatabaseBusy names it)
        new = _new_records(store, helios, refused, report)
        written = text is not None and _write_config(cfg_path, text)
        sha = config_sha256(cfg_path)
        name = _record(store, cfg, str(cfg_path.resolve()), sha, folder, new) if new else None
    finally:
        store.close()
    return PaintImport(str(db), str(cfg_path), sha, written, name, sum(len(v) for v in new.values()),
                       sum(r.already_imported for r in report.values()), report, refused,
                       time.perf_counter() - t0)


def _check_replaceable(path: Path, text: str) -> None:
    """Refuse to overwrite a configuration that is not the one this folder gives (an operator's
    edits, or another field's): it is used as it is with ``--config``."""
    if path.exists() and read_bytes(path, "configuration").decode("utf-8", "replace") != text:
        raise InputError(f"{path}: exists and is not the field configuration of this folder (edited, or "
                         "the folder's heliostats or targets changed); pass --config with it to import "
                         "into it as it is, or move it away")


def _write_config(path: Path, text: str) -> bool:
    if path.exists():
        return False  # the same text (checked before)
    write_atomic(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))
    return True


def _assess(cfg: PlantConfig, h: FolderHeliostat, refused: dict[str, str], notes: dict[str, str]
            ) -> HeliostatImport:
    """The per-heliostat checks of :class:`HeliostatImport` on the records that have a time."""
    out = HeliostatImport(len(h.records), note=refused.get(h.heliostat_id) or notes.get(h.heliostat_id))
    out.no_time = [r.record_id for r in h.records if r.utc is None]
    out.helios_only = [r.record_id for r in h.records if r.record.method != "UTIS"]
    if h.heliostat_id in refused:
        return out
    conf = cfg.heliostat(h.heliostat_id)
    kin = HeliostatKinematics.from_config(conf)
    az, el = conf.axes.azimuth.soft_limits, conf.axes.elevation.soft_limits
    miss = []
    for r in h.records:
        s = r.record.sample
        if r.utc is None:
            continue
        if not (az.min_steps <= s.az_steps <= az.max_steps and el.min_steps <= s.el_steps <= el.max_steps):
            out.outside_soft_limits += 1
        try:
            nominal = kin.normal(s.az_steps, s.el_steps)
        except ValueError:  # the configured stroke leaves the actuator triangle at these steps
            out.outside_triangle += 1
            continue
        measured = aim_normal(s.source_dir, kin.mirror_center(s.az_steps, s.el_steps), s.spot_enu)
        miss.append(math.acos(min(1.0, float(nominal @ measured))) * 1e3)
    out.nominal_miss_mrad = round(float(np.median(miss)), 2) if miss else None
    return out


def _new_records(store: CampaignStore, helios: list[FolderHeliostat], refused: dict[str, str],
                 report: dict[str, HeliostatImport]) -> dict[str, list[FolderRecord]]:
    """The records with a time not imported before, by heliostat; InputError naming a record
    imported before whose file has changed since."""
    before = {(r["heliostat_id"], r["record_id"]): r["sha256"] for r in
              store.query("SELECT heliostat_id, record_id, sha256 FROM imported_records WHERE source=?",
                          (SOURCE,))}
    new: dict[str, list[FolderRecord]] = {}
    for h in helios:
        if h.heliostat_id in refused:
            continue
        for r in h.records:
            sha = before.get((h.heliostat_id, r.record_id))
            if sha is None and r.utc is not None:
                new.setdefault(h.heliostat_id, []).append(r)
            elif sha is not None and sha != r.sha256:
                raise InputError(f"{r.path}: record {h.heliostat_id}_{r.record_id} was imported into "
                                 f"{store.path} before with other content; nothing was imported")
            elif sha is not None:
                report[h.heliostat_id].already_imported += 1
        report[h.heliostat_id].imported = len(new.get(h.heliostat_id, []))
    return new


def _seconds(utc: str) -> float:
    return datetime.fromisoformat(utc).timestamp()


def _record(store: CampaignStore, cfg: PlantConfig, cfg_path: str, sha: str, folder: Path,
            new: dict[str, list[FolderRecord]]) -> str:
    """One campaign of the new records, in one transaction; returns its name."""
    taken = {c.name for c in store.campaigns()}
    name = next(f"paint-import-{k}" for k in range(1, len(taken) + 2) if f"paint-import-{k}" not in taken)
    methods = Counter(r.record.method for rs in new.values() for r in rs)
    s = cfg.site
    meta = {"source": "PAINT", "folder": str(folder.resolve()),
            "site": [s.latitude_deg, s.longitude_deg, s.elevation_m], "methods": dict(methods)}
    now = utc_now()
    with store.tx() as db:
        cid = db.execute(
            "INSERT INTO campaigns (name, config_path, config_sha256, light_source, target, queue_json, "
            "started_utc, finished_utc, status, meta_json) VALUES (?,?,?,?,?,?,?,?,'finished',?)",
            (name, cfg_path, sha, "sun", cfg.calibration.target, json.dumps(list(new)), now, now,
             json.dumps(meta))).lastrowid
        for index, (hid, records) in enumerate(new.items()):
            first, last = records[0].utc, records[-1].utc
            run = db.execute(
                "INSERT INTO heliostat_runs (campaign_id, heliostat_id, queue_index, status, final_state, "
                "iterations, start_s, end_s, finished_utc) VALUES (?,?,?,'measured','imported',?,?,?,?)",
                (cid, hid, index, len(records), _seconds(first), _seconds(last), last)).lastrowid
            for i, r in enumerate(records):
                p, smp = r.record, r.record.sample
                m = db.execute(
                    "INSERT INTO measurements (run_id, iteration, az_steps, el_steps, source_e, source_n, "
                    "source_u, source_az_deg, source_el_deg, centroid_e, centroid_n, centroid_u, aim_e, "
                    "aim_n, aim_u, plant_time_s, measured_utc, target) "
                    "VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                    (run, i, round(smp.az_steps), round(smp.el_steps), *map(float, smp.source_dir),
                     p.sun_azimuth_deg, p.sun_elevation_deg, *map(float, smp.spot_enu),
                     *map(float, p.target.center_enu), _seconds(r.utc), r.utc, p.target.name)).lastrowid
                db.execute("INSERT INTO imported_records (measurement_id, source, heliostat_id, record_id, "
                           "method, sha256) VALUES (?,?,?,?,?,?)",
                           (m, SOURCE, hid, r.record_id, p.method, r.sha256))
    return name
