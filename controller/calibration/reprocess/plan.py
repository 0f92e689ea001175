"""Archive reprocessing, the plan: which pairs to re-analyse with which beam chain, in which
chunks, and what each heliostat's refit is given (docs/reprocess.md).

The storage layer fills :class:`Archive` from a source database
(:func:`controller.storage.reprocess.archive.read_archive`); everything here is decided on the client,
deterministically from the archive and the options: pairs in measurement-id order, chunks
within one campaign, refits in heliostat order.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from controller.calibration.records import MeasurementRecord, ModelRecord
from controller.calibration.reprocess.tasks import ChainSpec, PairResult, PairSpec, RefitSpec
from controller.config import PlantConfig, config_sha256, load_config
from controller.errors import HeliocalError, InputError

# Dask's scheduler costs about 1 ms per task; its documentation asks for tasks of 100 ms or more.
# Tasks are sized from the pairs' measured cost to last TASK_S (a margin over 0.1 s: a pair's
# cost varies with its spot and the worker's load), at most MAX_TASK_PAIRS pairs.
TASK_S = 0.3
FIRST_TASK_PAIRS = 4  # before any pair's cost is known
MAX_TASK_PAIRS = 512


@dataclass(frozen=True)
class StoredCampaign:
    """A campaign as reprocessing needs it: its configuration file and hash as recorded, its
    target, and its camera registration record (JSON text, "" when it made none)."""

    id: int
    name: str
    config_path: str
    config_sha256: str
    target: str
    registration_json: str


@dataclass(frozen=True)
class StoredPair:
    """One archived frame pair: ``low``/``high`` paths and SHA-256 as recorded, exposures (s)."""

    low: str
    high: str
    low_sha256: str
    high_sha256: str
    exposures: tuple[float, float]


@dataclass
class Archive:
    """What reprocessing reads from a source store."""

    campaigns: dict[int, StoredCampaign]
    measurements: list[MeasurementRecord]  # all, id order, with heliostat, campaign and run ids
    pairs: dict[int, StoredPair]  # measurement id -> its pair (a measurement without one is absent)
    models: dict[str, ModelRecord]  # heliostat -> latest model
    latest_run: dict[str, int]  # heliostat -> id of its latest run (a new model row refers to it)


@dataclass(frozen=True)
class Configs:
    """The configuration files the campaigns name, as they are now: path → (SHA-256, config);
    ``changed``: campaigns whose file differs from the one they were recorded with."""

    files: dict[str, tuple[str, PlantConfig]]
    changed: tuple[str, ...]


def load_configs(archive: Archive) -> Configs:
    """Read every configuration file the campaigns name (relative paths from the current
    folder). InputError names the campaign whose file is missing or invalid."""
    files: dict[str, tuple[str, PlantConfig]] = {}
    changed = []
    for c in archive.campaigns.values():
        path = os.path.abspath(c.config_path)
        if path not in files:
            if not Path(path).is_file():
                raise InputError(f"{path}: configuration of campaign {c.name!r} not found")
            try:
                files[path] = (config_sha256(path), load_config(path))
            except HeliocalError as exc:
                raise InputError(f"campaign {c.name!r}: {exc}") from None
        if files[path][0] != c.config_sha256:
            changed.append(c.name)
    return Configs(files, tuple(changed))


def measured_at(m: MeasurementRecord) -> datetime | None:
    """The measurement's time (a stamp without a zone is UTC), None when it is unreadable."""
    try:
        t = datetime.fromisoformat(m.measured_utc.replace("Z", "+00:00"))
    except (AttributeError, ValueError):
        return None
    return t if t.tzinfo is not None else t.replace(tzinfo=UTC)


def frame_path(recorded: str, campaign: str, images_dir: str | None) -> str:
    """Where a recorded frame is read, as an absolute path (workers have another current
    folder): the recorded path, or with ``images_dir`` (the archive moved or mounted elsewhere)
    ``images_dir/<campaign>/<file name>``, the archive's layout
    (:class:`controller.storage.images.ImageArchive`)."""
    if images_dir:
        return os.path.abspath(Path(images_dir) / campaign / Path(recorded).name)
    return os.path.abspath(recorded)


def in_scope(archive: Archive, since: datetime | None) -> list[MeasurementRecord]:
    """The measurements whose pairs are re-analysed: all, or those measured at or after
    ``since`` (a measurement with an unreadable stamp is included)."""
    if since is None:
        return list(archive.measurements)
    return [m for m in archive.measurements if (t := measured_at(m)) is None or t >= since]


def check_records(archive: Archive, configs: Configs) -> None:
    """Every measurement's record against its campaign's configuration, before any work is sent
    or any output created (:func:`plan_pairs` checks its scope the same way)."""
    seen: dict[int, set[str]] = {}
    for m in archive.measurements:
        _checked_campaign(archive, configs, m, seen)


def _checked_campaign(archive: Archive, configs: Configs, m: MeasurementRecord,
                      seen: dict[int, set[str]]) -> StoredCampaign:
    """The campaign of ``m``; InputError naming the measurement when its campaign, target or
    heliostat is gone or its aim point is not finite (``seen``: heliostats per checked campaign)."""
    c = archive.campaigns.get(m.campaign_id)
    if c is None:
        raise InputError(f"measurement {m.id}: its campaign (id {m.campaign_id}) is not in the database")
    path = os.path.abspath(c.config_path)
    if c.id not in seen:
        cfg = configs.files[path][1]
        try:
            camera = cfg.for_target(c.target).camera
        except HeliocalError:
            raise InputError(f"{path}: campaign {c.name!r} measured on target {c.target!r}, which the "
                             "configuration no longer has") from None
        if c.registration_json and camera.registration is None:
            raise InputError(f"{path}: campaign {c.name!r} was registered to its target but the "
                             f"camera of {c.target!r} has no camera.registration now")
        seen[c.id] = {h.id for h in cfg.heliostats}
    if m.heliostat_id not in seen[c.id]:
        raise InputError(f"{path}: heliostat {m.heliostat_id!r} (measurement {m.id}, campaign "
                         f"{c.name!r}) is not in the configuration any more; it cannot be re-analysed")
    aim = tuple(float(v) for v in m.aim_enu)
    if len(aim) != 3 or not all(math.isfinite(v) for v in aim):
        raise InputError(f"measurement {m.id} (campaign {c.name!r}): aim point {aim} is not 3 finite "
                         "coordinates")
    return c


def plan_pairs(archive: Archive, configs: Configs, scope: list[MeasurementRecord],
               images_dir: str | None) -> list[tuple[ChainSpec, PairSpec]]:
    """Each measurement of ``scope`` with the chain of its campaign, in measurement-id order
    (each record checked as :func:`check_records` does)."""
    specs: dict[int, ChainSpec] = {}
    seen: dict[int, set[str]] = {}
    out = []
    for m in sorted(scope, key=lambda m: m.id):
        c = _checked_campaign(archive, configs, m, seen)
        if c.id not in specs:
            path = os.path.abspath(c.config_path)
            sha, cfg = configs.files[path]
            lib = cfg.calibration.library
            specs[c.id] = ChainSpec(path, sha, c.target, c.registration_json,
                                    os.path.abspath(lib) if lib else "")
        p = archive.pairs.get(m.id)
        pair = PairSpec(m.id, m.heliostat_id, frame_path(p.low, c.name, images_dir) if p else "",
                        frame_path(p.high, c.name, images_dir) if p else "", p.low_sha256 if p else "",
                        p.high_sha256 if p else "", p.exposures if p else (0.0, 0.0),
                        tuple(float(v) for v in m.aim_enu))
        out.append((specs[c.id], pair))
    return out


class TaskSizer:
    """How many pairs the next task holds: :data:`TASK_S` of work at the mean cost per pair
    measured on the workers so far (:meth:`tell`), :data:`FIRST_TASK_PAIRS` until the first
    result, within [1, :data:`MAX_TASK_PAIRS`]."""

    def __init__(self) -> None:
        self.pairs = 0
        self.seconds = 0.0

    def tell(self, pairs: int, seconds: float) -> None:
        self.pairs += pairs
        self.seconds += seconds

    @property
    def size(self) -> int:
        if not self.pairs or self.seconds <= 0:
            return FIRST_TASK_PAIRS
        return max(1, min(MAX_TASK_PAIRS, math.ceil(TASK_S * self.pairs / self.seconds)))


def take_task(todo: Iterator[tuple[ChainSpec, PairSpec]],
              size: int) -> tuple[tuple[ChainSpec, tuple[PairSpec, ...]], ...]:
    """The next task from ``todo``: up to ``size`` consecutive pairs, grouped by campaign (each
    group one beam chain); empty at the end."""
    groups: list[tuple[ChainSpec, list[PairSpec]]] = []
    for _ in range(size):
        item = next(todo, None)
        if item is None:
            break
        if not groups or groups[-1][0] != item[0]:
            groups.append((item[0], []))
        groups[-1][1].append(item[1])
    return tuple((spec, tuple(pairs)) for spec, pairs in groups)


def reanalysed(m: MeasurementRecord, r: PairResult | None) -> MeasurementRecord:
    """``m`` as the new database will hold it: the re-analysis of its pair when there was one
    to analyse (``ok`` or ``no_beam``), as stored when the pair is missing or unreadable."""
    if r is None or r.status not in ("ok", "no_beam"):
        return m
    kw = {"centroid_enu": r.centroid_enu, "centroid_px": r.centroid_px, "error_mrad": r.error_mrad,
          "images": []}
    if r.matched or r.status == "no_beam":
        kw.update(matched_label=r.matched_label, match_distance=r.match_distance,
                  runner_up_label=r.runner_up_label, runner_up_distance=r.runner_up_distance)
    return dataclasses.replace(m, **kw)


def refit_specs(archive: Archive, configs: Configs, results: dict[int, PairResult]) -> list[RefitSpec]:
    """One refit per heliostat with measurements, in id order, under the configuration of its
    latest campaign. InputError when that configuration no longer lists the heliostat."""
    by_heliostat: dict[str, list[MeasurementRecord]] = {}
    for m in archive.measurements:
        by_heliostat.setdefault(m.heliostat_id, []).append(reanalysed(m, results.get(m.id)))
    out = []
    for hid in sorted(by_heliostat):
        ms = by_heliostat[hid]
        c = archive.campaigns[max(m.campaign_id for m in ms)]
        path = os.path.abspath(c.config_path)
        sha, cfg = configs.files[path]
        if hid not in {h.id for h in cfg.heliostats}:
            raise InputError(f"{path}: heliostat {hid} (measured in campaign {c.name!r}) is not in the "
                             "configuration any more; it cannot be refitted")
        out.append(RefitSpec(hid, path, sha, tuple(ms), archive.models.get(hid)))
    return out
