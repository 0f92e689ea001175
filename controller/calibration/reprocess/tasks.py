"""Archive reprocessing, the work of one task: re-analyse a chunk of stored frame pairs with the
current beam chain, or refit one heliostat's tracking model (docs/reprocess.md).

These functions run on Dask workers (:mod:`controller.calibration.reprocess.run` ships them);
they take and return small plain values — file paths, ids, records — never image arrays: a
worker reads the frames itself from the archive. Each worker process builds a
:class:`BeamChain` once per (configuration file, target, camera registration) and keeps it.
Nothing here writes anything.

Per pair the outcome is one of :data:`PAIR_STATUSES`: ``ok`` (a beam measured), ``no_beam``
(the chain finds no usable spot now: :class:`BeamNotFound` with its reason), ``missing`` (a
frame file is not there, or the measurement has no archived pair) or ``unreadable`` (a frame
that is not a regular file, is larger than :func:`frame_limit`, cannot be decoded, is not its
camera's size, or whose bytes no longer match the SHA-256 the archive recorded). A frame is
read like every other input (:func:`controller.io.files.read_bytes`): its kind and size are
checked before a byte is read.

A task refused for its input (a configuration edited mid-run, a record the configuration no
longer fits: a :class:`HeliocalError`) returns it as a :class:`Refused` value instead of
raising it: a raised one makes the worker log its traceback (on the user's terminal, for a
local cluster); the client raises it, one line (:func:`outcome`).
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import time
from dataclasses import dataclass

import numpy as np

from controller.calibration.cycle.beam_chain import BeamChain
from controller.calibration.cycle.model_update import fit_measurements
from controller.calibration.cycle.observations import BeamNotFound
from controller.calibration.night.daytime import model_covariance, sun_path
from controller.calibration.records import MeasurementRecord, ModelRecord
from controller.calibration.reprocess.chain import registration_from_record
from controller.config import PlantConfig, config_sha256, load_config
from controller.devices.camera import FramePair
from controller.errors import HeliocalError, InputError
from controller.geometry.aiming import pointing_error_mrad
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model.fit import predicted_error
from controller.io.files import read_bytes
from controller.io.images import decode_image

PAIR_STATUSES = ("ok", "no_beam", "missing", "unreadable")
FRAME_SLACK_BYTES = 1 << 20  # a PNG's chunks, filter bytes and zlib blocks over the raw pixels


def frame_limit(width_px: int, height_px: int) -> int:
    """The largest frame file of a ``width_px`` × ``height_px`` camera, bytes: 2 bytes a pixel
    (16-bit samples; a PNG stores incompressible pixels with well under 1 % overhead) plus
    :data:`FRAME_SLACK_BYTES`."""
    return 2 * width_px * height_px + FRAME_SLACK_BYTES


@dataclass(frozen=True)
class Refused:
    """A task's :class:`HeliocalError`, returned (module docstring)."""

    error: HeliocalError


def outcome(result):
    """A task's result on the client: raises the :class:`Refused` error, else ``result``."""
    if isinstance(result, Refused):
        raise result.error
    return result


@dataclass(frozen=True)
class ChainSpec:
    """What a worker needs to build the beam chain of one campaign: the configuration file
    (and the SHA-256 the client read, so a file edited mid-run is refused), the campaign's
    target, its stored camera registration (JSON text, "" without one) and the library file
    ("" without one: recognition is not re-run)."""

    config_path: str
    config_sha256: str
    target: str
    registration_json: str = ""
    library: str = ""


@dataclass(frozen=True)
class PairSpec:
    """One stored measurement's frame pair: the files (``low``/``high`` paths and the SHA-256
    the archive recorded; empty paths when none was archived), exposures (s), the heliostat and
    the aim point (m ENU) its error is measured from."""

    measurement_id: int
    heliostat_id: str
    low: str
    high: str
    low_sha256: str
    high_sha256: str
    exposures: tuple[float, float]
    aim_enu: tuple[float, float, float]


@dataclass(frozen=True)
class PairResult:
    """The re-analysis of one pair (module docstring for ``status``; ``detail`` says why for
    anything but ``ok``). Centroid in px (x col, y row) and m ENU, error in mrad; the match
    fields are None when no library re-ran recognition (``matched`` False)."""

    measurement_id: int
    status: str
    detail: str = ""
    centroid_px: tuple[float, float] | None = None
    centroid_enu: tuple[float, float, float] | None = None
    error_mrad: float | None = None
    matched: bool = False
    matched_label: str | None = None
    match_distance: float | None = None
    runner_up_label: str | None = None
    runner_up_distance: float | None = None


@functools.lru_cache(maxsize=8)
def _config(path: str, sha256: str) -> PlantConfig:
    if config_sha256(path) != sha256:
        raise InputError(f"{path}: configuration changed while reprocessing; rerun to start with the "
                         "new file")
    return load_config(path)


@functools.lru_cache(maxsize=32)
def chain_for(spec: ChainSpec) -> BeamChain:
    """The beam chain of ``spec``, built once per worker process."""
    from controller.recognition.library_io import load_library

    cfg = _config(spec.config_path, spec.config_sha256).for_target(spec.target)
    chain = BeamChain(cfg, load_library(spec.library) if spec.library else None)
    if spec.registration_json:
        chain.registration = registration_from_record(cfg, json.loads(spec.registration_json), chain.frame)
    return chain


def _frame(path: str, sha256: str, camera) -> np.ndarray:
    """The frame at ``path`` of a camera (``width_px`` × ``height_px``): a regular file within
    :func:`frame_limit`, its bytes those the archive recorded, its header the camera's size."""
    if not os.path.lexists(path):
        raise FileNotFoundError(f"{path}: frame not found")
    data = read_bytes(path, "frame", frame_limit(camera.width_px, camera.height_px))
    if sha256 and hashlib.sha256(data).hexdigest() != sha256:
        raise InputError(f"{path}: frame differs from the archive record (SHA-256)")
    return decode_image(data, path, shape=(camera.height_px, camera.width_px), written_here=bool(sha256))


def analyse_pair(chain: BeamChain, heliostat_pos: np.ndarray, pair: PairSpec) -> PairResult:
    """Registration, HDR merge, beam analysis, centroid and recognition of one stored pair,
    through the same :class:`BeamChain` calls a campaign makes (a clipped spot is not a
    measurement: ``no_beam``)."""
    mid = pair.measurement_id
    if not pair.low or not pair.high:
        return PairResult(mid, "missing", "no frame pair archived for this measurement")
    try:
        camera = chain.cfg.camera
        low, high = _frame(pair.low, pair.low_sha256, camera), _frame(pair.high, pair.high_sha256, camera)
    except FileNotFoundError as exc:
        return PairResult(mid, "missing", str(exc))
    except InputError as exc:
        return PairResult(mid, "unreadable", str(exc))
    try:
        hdr = chain.merge(FramePair(low, high, pair.exposures, 0.0))
        obs = chain.analyze(hdr)
    except BeamNotFound as exc:
        return PairResult(mid, "no_beam", str(exc))
    except HeliocalError as exc:  # a pair the merge refuses (size, dtype): the file is at fault
        return PairResult(mid, "unreadable", f"{pair.low}: {exc}")
    m = chain.match(obs)
    enu = tuple(float(c) for c in obs.centroid_enu)
    return PairResult(
        mid, "ok", "", (float(obs.centroid_px[0]), float(obs.centroid_px[1])), enu,
        pointing_error_mrad(heliostat_pos, pair.aim_enu, enu), chain.library is not None,
        None if m is None or m.unknown else m.label, None if m is None else float(m.distance),
        None if m is None else m.runner_up, None if m is None else m.runner_up_distance)


def analyse_chunk(spec: ChainSpec, pairs: tuple[PairSpec, ...]) -> list[PairResult]:
    """One task: every pair of a chunk (all of one campaign), in the order given."""
    chain = chain_for(spec)
    cfg = chain.cfg
    out = []
    for p in pairs:
        pos = np.asarray(cfg.heliostat(p.heliostat_id).position_enu_m, float)
        out.append(analyse_pair(chain, pos, p))
    return out


def analyse_timed(groups: tuple[tuple[ChainSpec, tuple[PairSpec, ...]], ...]
                  ) -> tuple[list[PairResult], float] | Refused:
    """One task of several chunks (a night's passes are campaigns of their own: one task may
    hold many): :func:`analyse_chunk` of each, and the seconds they took on the worker (the
    client sizes the next tasks from them, :class:`controller.calibration.reprocess.plan.TaskSizer`)."""
    t0 = time.perf_counter()
    try:
        out = [r for spec, pairs in groups for r in analyse_chunk(spec, pairs)]
    except HeliocalError as exc:
        return Refused(exc)
    return out, time.perf_counter() - t0


@dataclass(frozen=True)
class RefitSpec:
    """One heliostat's refit: its configuration, every measurement of it (re-analysed where the
    pair was, as stored otherwise) and the model the source database holds."""

    heliostat_id: str
    config_path: str
    config_sha256: str
    measurements: tuple[MeasurementRecord, ...]
    old_model: ModelRecord | None


@dataclass(frozen=True)
class RefitResult:
    """The refitted ``model`` (None when the measurements identify no term) and the comparison
    with the old one: the terms that moved by more than the new model's 1-σ
    (``moved``: key → (old, new, σ)), and each model's (the nominal model with the prior σ for
    none) predicted daytime error (mrad RMS over
    the evaluation sun path at the calibration target, from its own covariance)."""

    heliostat_id: str
    model: ModelRecord | None
    moved: dict[str, tuple[float, float, float]]
    changed: bool
    old_predicted_mrad: float | None
    new_predicted_mrad: float | None


@functools.lru_cache(maxsize=4)
def _sun_directions(config_path: str, sha256: str) -> np.ndarray:
    return sun_path(_config(config_path, sha256).site).directions


def _predicted(cfg: PlantConfig, kin: HeliostatKinematics, model: ModelRecord | None, dirs) -> float | None:
    m, cov = model_covariance(model, cfg.calibration.model)
    try:
        return predicted_error(kin, m, cov, dirs, np.asarray(cfg.target().center_enu_m, float)).rms
    except InputError:  # the heliostat reaches no aim on the evaluation path
        return None


def moved_terms(old: ModelRecord | None, new: ModelRecord | None) -> dict[str, tuple[float, float, float]]:
    """Terms whose value moved by more than the new model's 1-σ: key → (old, new, σ). A term
    the old model lacks counts from 0 (the nominal value)."""
    if old is None or new is None:
        return {}
    out = {}
    for key, v in sorted(new.params.items()):
        s = new.sigma.get(key)
        o = float(old.params.get(key, 0.0))
        if s is not None and math.isfinite(s) and abs(float(v) - o) > s:
            out[key] = (o, float(v), float(s))
    return out


def refit_heliostat(spec: RefitSpec) -> RefitResult | Refused:
    """One task: :func:`refit` (its :class:`HeliocalError` returned, module docstring)."""
    try:
        return refit(spec)
    except HeliocalError as exc:
        return Refused(exc)


def refit(spec: RefitSpec) -> RefitResult:
    """One task: fit the heliostat's model to ``spec.measurements`` exactly as a campaign does
    (:func:`controller.calibration.cycle.pointing.fit_measurements`) and compare it with the old
    model. ``changed``: a term moved by more than its σ, or a heliostat without a model got
    one. Without a new model (nothing identified) the old one stays in force."""
    cfg = _config(spec.config_path, spec.config_sha256)
    h = cfg.heliostat(spec.heliostat_id)
    kin = HeliostatKinematics.from_config(h)
    ordered = sorted(spec.measurements, key=lambda m: m.id or 0)
    new = fit_measurements(kin, ordered, cfg.calibration.model)
    moved = moved_terms(spec.old_model, new)
    dirs = _sun_directions(spec.config_path, spec.config_sha256)
    changed = bool(moved) or (new is not None and spec.old_model is None)
    return RefitResult(spec.heliostat_id, new, moved, changed, _predicted(cfg, kin, spec.old_model, dirs),
                       _predicted(cfg, kin, new, dirs) if new is not None else None)
