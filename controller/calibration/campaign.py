"""Nightly calibration campaign: the queue, the pipeline, resumption and live progress.

A campaign calibrates a list of heliostats against one target under one light source (a
lamp at night). It knows only the plant configuration, drives from
:class:`controller.devices.factory.LinkPool`, a :class:`DoubleCcdCamera` and the record
store; nothing here knows whether the plant is simulated.

* **Queue** (:func:`order_queue`): heliostats sorted by their estimated slew time from where
  they are to their standby point, shortest first. The first slew cannot be hidden behind
  another heliostat's measurement; every later one gets more time to finish, so the target
  waits least. The queue is stored with the campaign, so a resumed run keeps it.
* **Pipeline**: up to ``pipeline_depth`` heliostats run their cycle at once. Each slews to its
  standby point in parallel; the :class:`TargetGate` then lets them onto the target one at a
  time, in queue order. So while heliostat k is measured, k+1… are already parked at standby.
* **Resumable**: each heliostat's record is committed in one transaction when its cycle ends
  (:meth:`CampaignStore.record_run`). After ``kill -9`` the rerun skips the heliostats already
  recorded; a heliostat interrupted mid-cycle has no record and is calibrated again.
* **Timing** is read from the injected plant ``clock`` (seconds), so throughput is in plant
  time; target occupancy = from the approach command until the beam is parked at standby.

Measurement chain per capture (docs/campaigns.md): HDR merge (controller.imaging.hdr) →
beam centroid + Hu moments (controller.imaging.beam) → pixel → target-plane ENU
(:class:`TargetFrame`) → pointing error → library match (controller.calibration.library).
"""

from __future__ import annotations

import hashlib
import json
import math
import sqlite3
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from controller.calibration.machine import (
    BeamNotFound,
    CalibrationCycle,
    CycleContext,
    Match,
    Observation,
    Step,
    TargetGate,
)
from controller.config import Heliostat, PlantConfig, Target
from controller.devices.drive import DriveLimits
from controller.errors import HeliocalError, InputError
from controller.geometry.aiming import aim_normal, source_direction
from controller.geometry.correction import correction_from_offset
from controller.geometry.error_model import (
    Measurement,
    TrackingErrorParams,
    fit_tracking_errors,
    steps_for_normal_with_errors,
)
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.vectors import unit
from controller.storage.db import CampaignStore, ImageRecord, MeasurementRecord, ModelRecord

_UP = np.array([0.0, 0.0, 1.0])
# Below this spread of joint angles the measurements cannot separate tilt and non-orthogonality
# from the reference offsets: the fit then estimates only the two offsets (error_model docs).
_FULL_FIT_SPREAD_RAD = math.radians(10.0)


# -- the target as the camera sees it -----------------------------------------------------------
@dataclass(frozen=True)
class TargetFrame:
    """Rectified camera view of a planar target (pixel grid over the target plane).

    Image x (column) runs along ``u = unit(up × normal)`` (for a north-facing target that is
    west, i.e. image left = east, as in the PAINT images), image y (row) along ``v = u × normal``
    (down). Pixel (0, 0) is the centre of the top-left pixel, half a pixel inside the corner
    ``center - W/2 u - H/2 v``. Pixels are square (Hu moments are not invariant to an
    anisotropic scale): the pitch is the larger of target width/cols and height/rows, so the
    view ``W x H`` covers the whole target and is centred on it.
    """

    center: np.ndarray
    normal: np.ndarray
    u: np.ndarray
    v: np.ndarray
    width_m: float
    height_m: float
    shape: tuple[int, int]

    @classmethod
    def from_config(cls, target: Target, shape: tuple[int, int]) -> TargetFrame:
        n = unit(np.asarray(target.normal, float))
        u = np.cross(_UP, n)
        if np.linalg.norm(u) < 1e-9:
            u = np.array([1.0, 0.0, 0.0]) - n[0] * n
        u = unit(u)
        rows, cols = int(shape[0]), int(shape[1])
        pitch = max(float(target.width_m) / cols, float(target.height_m) / rows)
        return cls(np.asarray(target.center_enu_m, float), n, u, np.cross(u, n), cols * pitch, rows * pitch,
                   (rows, cols))

    def pixel_to_enu(self, x_px: float, y_px: float) -> np.ndarray:
        """ENU point (3,) on the target plane for pixel coordinates (x = column, y = row)."""
        du, dv = self.width_m / self.shape[1], self.height_m / self.shape[0]
        return (self.center + ((x_px + 0.5) * du - self.width_m / 2) * self.u
                + ((y_px + 0.5) * dv - self.height_m / 2) * self.v)

    def side(self, heliostat_pos: np.ndarray) -> np.ndarray:
        """Unit in-plane direction beside the target on the heliostat's own side (±u)."""
        return self.u if float((np.asarray(heliostat_pos) - self.center) @ self.u) >= 0 else -self.u


INTERRUPTED = "interrupted by the operator"


class UnsafePath(HeliocalError):
    """No slew keeps the beam off the target (beam safety); nothing was sent."""


# -- geometry of one heliostat ------------------------------------------------------------------
class GeometryPointing:
    """:class:`controller.calibration.machine.Pointing` on controller.geometry.

    The aim point is the target centre; the standby point lies ``standby_offset_m`` beside it in
    the target plane, on the heliostat's own side, so the approach is a short horizontal slew.
    """

    def __init__(self, heliostat: Heliostat, target: Target, source, frame: TargetFrame,
                 standby_offset_m: float, current_steps: tuple[int, int] | None = None) -> None:
        self.kin = HeliostatKinematics.from_config(heliostat)
        self.heliostat_pos = np.asarray(heliostat.position_enu_m, float)
        self.target = target
        self.aim_point = np.asarray(target.center_enu_m, float)
        self.source_dir = np.asarray(source_direction(source, self.heliostat_pos), float)
        self.heliostat = heliostat
        self.frame = frame
        self.standby_point = self.aim_point + standby_offset_m * frame.side(self.heliostat_pos)
        if current_steps is not None:
            # Park on the side the slew from the present pose reaches first (azimuth steps
            # closer to the present ones), so the beam does not pass the target on its way.
            best = None
            for side in (frame.u, -frame.u):
                point = self.aim_point + standby_offset_m * side
                try:
                    az, _ = self.kin.aim(self.source_dir, point)
                except Exception:  # unreachable side
                    continue
                if best is None or abs(az - current_steps[0]) < best[0]:
                    best = (abs(az - current_steps[0]), point)
            if best is not None:
                self.standby_point = best[1]

    def beam_on_target(self, az_steps: float, el_steps: float, margin_m: float = 2.0) -> bool:
        """Whether the nominal reflected central ray lands on the target grown by ``margin_m``
        (spot radius plus model error)."""
        try:
            hit = self.kin.spot(az_steps, el_steps, self.source_dir, self.aim_point, self.frame.normal)
        except (ValueError, FloatingPointError):
            return False  # the beam points away from the target plane
        d = hit - self.aim_point
        return (abs(float(d @ self.frame.u)) <= self.target.width_m / 2 + margin_m
                and abs(float(d @ self.frame.v)) <= self.target.height_m / 2 + margin_m)

    def path_to(self, start: tuple[int, int], end: tuple[int, int]) -> list[tuple[int, int]]:
        """Waypoints from ``start`` to ``end`` (a point off the target) along which the beam
        never crosses the target: both axes together, else elevation first, else azimuth first.
        The motion model moves each axis at its configured speed (acceleration ignored).
        Raises RuntimeError when no such path exists."""
        ax = self.heliostat.axes
        speed = np.array([ax.azimuth.speed_steps_per_s, ax.elevation.speed_steps_per_s])

        def clear(plan: list[tuple[int, int]]) -> bool:
            # A beam that starts on the target may leave it; once off it must never enter.
            inside = self.beam_on_target(*start)
            for a, b in zip([start] + plan[:-1], plan, strict=True):
                a_, b_ = np.asarray(a, float), np.asarray(b, float)
                dur = np.abs(b_ - a_) / speed
                total = float(dur.max())
                for t in np.linspace(0.0, total, 120 if total > 0 else 1):
                    frac = np.where(dur > 0, np.minimum(1.0, t / np.where(dur > 0, dur, 1.0)), 1.0)
                    on = self.beam_on_target(*(a_ + frac * (b_ - a_)))
                    if on and not inside:
                        return False
                    inside = inside and on
            return True

        plans = ([end], [(start[0], end[1]), end], [(end[0], start[1]), end])
        for plan in plans:
            if clear(plan):
                return [p for p in plan if p != start]
        raise UnsafePath(f"{self.heliostat.id}: no slew from {start} to standby {end} keeps the beam "
                         "off the target")

    def _steps(self, point: np.ndarray, model: ModelRecord | None) -> tuple[int, int]:
        if model is None:
            return self.kin.aim(self.source_dir, point)
        n = aim_normal(self.source_dir, self.heliostat_pos, point)
        return steps_for_normal_with_errors(self.kin, TrackingErrorParams.from_dict(model.params), n)

    def aim_steps(self, model: ModelRecord | None) -> tuple[int, int]:
        return self._steps(self.aim_point, model)

    def standby_steps(self, model: ModelRecord | None) -> tuple[int, int]:
        return self._steps(self.standby_point, model)

    def fine_correction(self, az_steps: int, el_steps: int, offset_enu: np.ndarray) -> Step:
        c = correction_from_offset(self.kin, az_steps, el_steps, self.source_dir, None, self.target,
                                   offset_enu)
        return Step(c.daz_deg, c.del_deg, c.daz_steps, c.del_steps)

    def coarse_correction(self, az_steps: int, el_steps: int, daz_deg: float, del_deg: float) -> Step:
        alpha, eps = self.kin.angles(az_steps, el_steps)
        daz = self.kin.azimuth.steps_float(alpha + math.radians(daz_deg)) - az_steps
        dele = self.kin.elevation.steps_float(eps + math.radians(del_deg)) - el_steps
        return Step(daz_deg, del_deg, int(round(float(daz))), int(round(float(dele))))

    def fit(self, measurements: list[MeasurementRecord], prior: ModelRecord | None) -> ModelRecord | None:
        """Tracking-error fit over all measurements of this heliostat (earlier runs included).

        With a small spread of joint angles only the two reference offsets are fitted (the
        other parameters keep their prior values)."""
        ms = [Measurement(np.asarray(m.source_dir), m.az_steps, m.el_steps, np.asarray(m.centroid_enu))
              for m in measurements if m.centroid_enu is not None]
        if not ms:
            return prior
        ang = np.array([self.kin.angles(m.az_steps, m.el_steps) for m in ms])
        spread = float(np.max(np.ptp(ang, axis=0)))
        initial = TrackingErrorParams.from_dict(prior.params) if prior else TrackingErrorParams()
        if spread >= _FULL_FIT_SPREAD_RAD and len(ms) >= 4:
            res = fit_tracking_errors(self.kin, ms, initial=initial)
        else:
            res = fit_tracking_errors(self.kin, ms, fit=("az_offset", "el_offset"), initial=initial)
        sigma = {k: (v if math.isfinite(v) else None) for k, v in res.sigma.to_dict().items()}
        return ModelRecord(res.params.to_dict(), sigma, float(res.residual_mrad_rms), len(ms))


# -- the measurement chain ------------------------------------------------------------------------
class BeamChain:
    """HDR merge → beam analysis → target ENU → library match, for one plant configuration."""

    def __init__(self, cfg: PlantConfig, library=None, threshold: float | None = None,
                 min_peak_fraction: float = 0.02) -> None:
        from controller.imaging.crf import Crf

        cam = cfg.camera
        self.cfg = cfg
        self.crf = Crf.load(cam.crf_file) if cam.crf_file else None
        self.frame = TargetFrame.from_config(cfg.target(), (cam.height_px, cam.width_px))
        self.threshold = cfg.calibration.threshold if threshold is None else threshold
        self.centroid_threshold = cfg.calibration.centroid_threshold
        self.library = library
        self.matcher = library.matcher() if library is not None else None
        self.min_peak_fraction = min_peak_fraction
        self._mergers: dict[tuple[float, float], Any] = {}
        self._lock = threading.Lock()

    def merge(self, frame) -> np.ndarray:
        from controller.imaging.hdr import HdrMerger

        key = tuple(float(t) for t in frame.exposures)
        with self._lock:
            m = self._mergers.get(key)
            if m is None:
                cam = self.cfg.camera
                m = self._mergers[key] = HdrMerger(key, self.crf, "raised-cosine", cam.dark_offset_counts,
                                                   bit_depth=cam.bit_depth, read_noise=cam.read_noise_counts,
                                                   full_well=cam.full_well_electrons)
        return m.merge(frame.low, frame.high)

    def analyze(self, hdr: np.ndarray) -> Observation:
        import cv2

        from controller.imaging.beam import analyze, subtract_background

        try:
            r = analyze(hdr, threshold=self.threshold, background="auto")
        except InputError as exc:
            raise BeamNotFound(f"no beam spot in the image ({exc})") from None
        if r.pixels < 4:
            raise BeamNotFound(f"no beam spot in the image (only {r.pixels} pixels above threshold)")
        # The pointing centroid is the beam's energy centroid: every pixel above a low
        # threshold (calibration.centroid_threshold), not only the main region analyze()
        # keeps for the shape. A detached or dim lobe (canting error) carries beam energy
        # and must pull the aim too (docs/campaigns.md).
        signal = subtract_background(hdr, r.background)
        smooth = cv2.GaussianBlur(signal.astype(np.float32), (0, 0), 1.0)
        above = smooth > self.centroid_threshold * float(smooth.max())
        rows, cols = hdr.shape
        edges = [name for name, e in (("top", above[0]), ("bottom", above[-1]), ("left", above[:, 0]),
                                      ("right", above[:, -1])) if e.any()]
        if edges:  # a clipped spot's centroid is biased towards the inside
            raise BeamNotFound(f"beam spot clipped by the {'/'.join(edges)} edge of the camera view")
        w = np.where(above, signal, 0.0)
        tot = float(w.sum())
        if not tot > 0:
            raise BeamNotFound("no beam energy above the threshold")
        x = float(w.sum(axis=0) @ np.arange(cols)) / tot
        y = float(w.sum(axis=1) @ np.arange(rows)) / tot
        return Observation((x, y), tuple(self.frame.pixel_to_enu(x, y)), np.asarray(r.hu), float(r.peak))

    def match(self, hu: np.ndarray) -> Match | None:
        if self.matcher is None:
            return None
        from controller.calibration.library import hu_features

        m = self.matcher.match(hu_features(hu, self.library.features))
        entry = self.library.entries[m.index]
        corr = entry.correction
        return Match(m.label, m.distance, m.runner_up_label, m.runner_up_distance, m.unknown,
                     (float(corr["az_deg"]), float(corr["el_deg"])) if corr else None)


# -- queue ------------------------------------------------------------------------------------------
def slew_time_s(steps: float, speed: float, accel: float) -> float:
    """Duration of a trapezoidal (or triangular) move of ``steps`` at ``speed``/``accel``, s."""
    d = abs(float(steps))
    ramp = speed * speed / accel
    return 2 * math.sqrt(d / accel) if d < ramp else d / speed + speed / accel


def order_queue(cfg: PlantConfig, ids: list[str], current: dict[str, tuple[int, int]],
                pointing: dict[str, GeometryPointing]) -> list[str]:
    """Heliostats by estimated slew time from ``current`` steps to standby, shortest first
    (ties by id, so the order is reproducible)."""
    def t(hid: str) -> float:
        h = cfg.heliostat(hid)
        try:
            saz, sel = pointing[hid].standby_steps(None)
        except Exception:  # unreachable standby: put it last, its cycle will report why
            return math.inf
        az, el = current.get(hid, (saz, sel))
        ax = h.axes
        a, e = ax.azimuth, ax.elevation
        return max(slew_time_s(saz - az, a.speed_steps_per_s, a.acceleration_steps_per_s2),
                   slew_time_s(sel - el, e.speed_steps_per_s, e.acceleration_steps_per_s2))

    return sorted(ids, key=lambda h: (t(h), h))


# -- campaign ----------------------------------------------------------------------------------------
@dataclass
class CampaignResult:
    campaign_id: int
    name: str
    resumed: bool
    runs: list  # sqlite3.Row of every heliostat run of the campaign (earlier sessions too)
    makespan_s: float  # plant time of this session, first start to last end
    sequential_estimate_s: float  # same work one after another (sum of slews + occupancy)
    halted: str | None = None  # why the campaign stopped early (target blocked), else None
    session_runs: int = 0


@dataclass
class SimulationHooks:
    """Optional knowledge only a simulated plant has (None in a real field)."""

    true_error_mrad: Callable[[str], float] | None = None
    truth_label: Callable[[str], str | None] | None = None


@dataclass
class CampaignOptions:
    name: str = "campaign"
    pipeline_depth: int = 4
    settle_s: float = 0.5
    save_images: bool = True
    image_dir: Path | None = None
    timeouts: dict[str, float] = field(default_factory=dict)
    move_timeout_s: float = 120.0
    poll_s: float = 0.1  # status polling interval, plant seconds
    progress: bool = True


def config_sha256(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


class Campaign:
    """Runs (or resumes) one campaign; see the module docstring."""

    def __init__(self, cfg: PlantConfig, config_path: str | Path, store: CampaignStore, pool, camera, *,
                 heliostat_ids: list[str] | None = None, library=None, options: CampaignOptions | None = None,
                 clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep,
                 hooks: SimulationHooks | None = None, simulated: bool = False,
                 meta: dict | None = None, compute=None,
                 observer: Callable[[str, str], None] | None = None) -> None:
        self.cfg = cfg
        self.config_path = str(config_path)
        self.store = store
        self.pool = pool
        self.camera = camera
        self.ids = list(heliostat_ids) if heliostat_ids is not None else [h.id for h in cfg.heliostats]
        for hid in self.ids:
            cfg.heliostat(hid)  # ConfigError naming an unknown id
        self.opt = options or CampaignOptions(settle_s=cfg.calibration.settle_s,
                                              pipeline_depth=cfg.calibration.pipeline_depth)
        if self.opt.pipeline_depth < 1:
            raise InputError(f"pipeline depth must be at least 1, got {self.opt.pipeline_depth}")
        self.clock = clock
        self.sleep = sleep
        self.hooks = hooks or SimulationHooks()
        self.simulated = simulated
        self.meta = meta or {}
        self.compute = compute
        self.observer = observer  # (heliostat, state) on every state change, e.g. for a UI
        self.chain = BeamChain(cfg, library)
        self._camera_lock = threading.Lock()
        self._drives: dict[str, Any] = {}
        self._link_locks: dict[tuple, threading.Lock] = {}
        self.states: dict[str, str] = {}

    # -- devices ------------------------------------------------------------------------------
    def drive(self, hid: str):
        if hid not in self._drives:
            h = self.cfg.heliostat(hid)
            link = h.link
            key = (link.kind, getattr(link, "device", None) or f"{link.host}:{link.port}")
            lock = self._link_locks.setdefault(key, threading.Lock())
            self._drives[hid] = _SerialisedDrive(self.pool.drive(link, DriveLimits.from_axes(h.axes)), lock)
        return self._drives[hid]

    def _capture(self):
        with self._camera_lock:
            return self.camera.capture()

    # -- run ----------------------------------------------------------------------------------
    def run(self) -> CampaignResult:
        cal = self.cfg.calibration
        source = self.cfg.light_source()
        target = self.cfg.target()
        current = {}
        for hid in self.ids:
            try:
                st = self.drive(hid).status()
                current[hid] = (st.az_steps, st.el_steps)
            except Exception:  # unreachable now: its cycle will record the failure
                pass
        pointing = {hid: GeometryPointing(self.cfg.heliostat(hid), target, source, self.chain.frame,
                                          cal.standby_offset_m, current.get(hid)) for hid in self.ids}
        existing = self._existing()
        queue = existing if existing is not None else order_queue(self.cfg, self.ids, current, pointing)
        site = self.cfg.site
        self.meta.setdefault("site", [site.latitude_deg, site.longitude_deg, site.elevation_m])
        self.meta.setdefault("target_normal", list(target.normal))
        cid, resumed = self.store.open_campaign(
            self.opt.name, config_path=self.config_path, config_sha256=config_sha256(self.config_path),
            light_source=source.id, target=target.id, queue=queue, simulated=self.simulated, meta=self.meta)
        done = self.store.done_heliostats(cid)
        todo = [(i, hid) for i, hid in enumerate(queue) if hid not in done]
        gate = TargetGate()
        t0 = self.clock()
        session: list = []
        halted = None
        with _Progress(self.opt.progress and bool(todo), len(queue), len(done), self.clock) as progress:
            cycles: dict[str, CalibrationCycle] = {}
            stop = threading.Event()

            def one(ticket: int, qi: int, hid: str):
                if gate.blocked or stop.is_set():
                    gate.release(ticket)
                    return None
                cyc = CalibrationCycle(self._context(hid, qi, ticket, gate, pointing[hid], progress))
                cycles[hid] = cyc
                rec = cyc.run()
                cycles.pop(hid, None)
                if rec.fault_cause == INTERRUPTED:
                    return None  # parked, not recorded: a resume calibrates it again
                if gate.blocked and rec.final_state != "aborted" and rec.iterations == 0 \
                        and rec.status == "failed":
                    return None  # never reached the target because another beam blocked it: not recorded
                self.store.record_run(cid, rec)
                progress.finished(hid, rec)
                return rec

            with ThreadPoolExecutor(max_workers=self.opt.pipeline_depth,
                                    thread_name_prefix="cycle") as pool:
                futures = [pool.submit(one, t, qi, hid) for t, (qi, hid) in enumerate(todo)]
                try:
                    for f in futures:
                        rec = f.result()
                        if rec is not None:
                            session.append(rec)
                except KeyboardInterrupt:
                    # Ctrl-C: every cycle in flight parks its beam (fault path), nothing new starts.
                    stop.set()
                    for cyc in list(cycles.values()):
                        cyc.request_abort(INTERRUPTED)
                    pool.shutdown(wait=True, cancel_futures=True)
                    self.store.finish_campaign(cid, "incomplete")
                    raise
        if gate.blocked:
            halted = ("a beam may have been left on the target (heliostat could not be parked): "
                      "campaign halted")
        t1 = self.clock()
        status = "halted" if halted else ("finished" if len(self.store.done_heliostats(cid)) == len(queue)
                                          else "incomplete")
        seq = sum(_sequential_share(r) for r in session)
        self.store.finish_campaign(cid, status)
        return CampaignResult(cid, self.opt.name, resumed, self.store.runs(cid), t1 - t0, seq, halted,
                              len(session))

    def _existing(self) -> list[str] | None:
        row = self.store.campaign_by_name(self.opt.name)
        return None if row is None else json.loads(row["queue_json"])

    def _context(self, hid: str, qi: int, ticket: int, gate: TargetGate, pointing: GeometryPointing,
                 progress) -> CycleContext:
        cal = self.cfg.calibration
        chain = self.chain
        history = [_measurement_from_row(r) for r in self.store.measurements(heliostat_id=hid)]
        camera = _CameraView(self._capture)

        def save(frame, hdr, iteration):
            return self._save_images(hid, iteration, frame) if self.opt.save_images else []

        hooks = self.hooks
        return CycleContext(
            heliostat_id=hid, queue_index=qi, ticket=ticket, drive=self.drive(hid), camera=camera,
            pointing=pointing,
            merge=chain.merge, analyze=chain.analyze, match=chain.match, gate=gate,
            model=self.store.latest_model(hid), history=history, tolerance_mrad=cal.tolerance_mrad,
            max_iterations=cal.max_iterations, settle_s=self.opt.settle_s,
            move_timeout_s=self.opt.move_timeout_s, poll_s=self.opt.poll_s, clock=self.clock,
            sleep=self.sleep, timeouts=self.opt.timeouts, save_images=save,
            truth_error=(lambda: hooks.true_error_mrad(hid)) if hooks.true_error_mrad else None,
            truth_label=hooks.truth_label(hid) if hooks.truth_label else None,
            on_state=self._on_state_fn(progress), **({"compute": self.compute} if self.compute else {}))

    def _on_state_fn(self, progress):
        def on_state(hid: str, state: str) -> None:
            self.states[hid] = state
            progress.state(hid, state)
            if self.observer is not None:
                self.observer(hid, state)
        return on_state

    def _save_images(self, hid: str, iteration: int, frame) -> list[ImageRecord]:
        import cv2

        from controller.io.images import write_atomic

        out = []
        base = self.opt.image_dir or Path(self.store.path).parent / "images"
        for kind, img in (("low", frame.low), ("high", frame.high)):
            p = base / self.opt.name / f"{hid}-it{iteration}-{kind}.png"

            def w(t: Path, img=img) -> None:
                if not cv2.imwrite(str(t), img):
                    raise OSError(f"could not write {t}")
            write_atomic(p, w)
            out.append(ImageRecord(kind, str(p), hashlib.sha256(p.read_bytes()).hexdigest(),
                                   tuple(float(t) for t in frame.exposures)))
        return out


def _sequential_share(r) -> float:
    """Plant time the run would add one after another: its slew to standby plus its time from
    the approach to the end (its wait for the target does not exist then)."""
    def g(k: str):
        return r[k] if isinstance(r, sqlite3.Row) else getattr(r, k)

    prep = (g("at_standby_s") - g("start_s")) if g("at_standby_s") is not None else 0.0
    start = g("on_target_s") if g("on_target_s") is not None else (g("at_standby_s") or g("start_s"))
    busy = g("end_s") - start
    return max(0.0, prep) + max(0.0, busy)


def _measurement_from_row(row) -> MeasurementRecord:
    c = None if row["centroid_e"] is None else (row["centroid_e"], row["centroid_n"], row["centroid_u"])
    return MeasurementRecord(row["iteration"], row["az_steps"], row["el_steps"],
                             (row["source_e"], row["source_n"], row["source_u"]), row["source_az_deg"],
                             row["source_el_deg"], (row["aim_e"], row["aim_n"], row["aim_u"]),
                             row["plant_time_s"], centroid_enu=c, error_mrad=row["error_mrad"])


class _CameraView:
    """The shared camera as each cycle sees it (captures serialised by the campaign)."""

    def __init__(self, capture: Callable[[], Any]) -> None:
        self.capture = capture


class _SerialisedDrive:
    """A drive whose calls are serialised with the other drives on the same bus/connection."""

    def __init__(self, drive, lock: threading.Lock) -> None:
        self._d = drive
        self._lock = lock
        self.limits = drive.limits
        self.unit = drive.unit

    def __getattr__(self, name: str):
        attr = getattr(self._d, name)
        if not callable(attr):
            return attr

        def call(*a, **k):
            with self._lock:
                return attr(*a, **k)
        return call


class _Progress:
    """rich live progress (bar with ETA, current states) when enabled; silent otherwise."""

    def __init__(self, enabled: bool, total: int, already: int, clock) -> None:
        self.enabled = enabled
        self.total = total
        self.already = already
        self._states: dict[str, str] = {}
        self._lock = threading.Lock()

    def __enter__(self) -> _Progress:
        if self.enabled:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

            self._p = Progress(TextColumn("[bold]campaign"), BarColumn(), MofNCompleteColumn(),
                               TextColumn("ETA"), TimeRemainingColumn(), TextColumn("{task.description}"),
                               transient=False)
            self._p.__enter__()
            self._task = self._p.add_task("", total=self.total, completed=self.already)
        return self

    def __exit__(self, *exc) -> None:
        if self.enabled:
            self._p.__exit__(*exc)

    def state(self, hid: str, state: str) -> None:
        if not self.enabled:
            return
        with self._lock:
            if state in ("done", "stowed", "aborted"):
                self._states.pop(hid, None)
            else:
                self._states[hid] = state
            desc = " ".join(f"{h}:{s}" for h, s in sorted(self._states.items())
                            if s not in ("preparing",))[:90]
            self._p.update(self._task, description=desc)

    def finished(self, hid: str, rec) -> None:
        if self.enabled:
            self._p.advance(self._task)


# -- summary -----------------------------------------------------------------------------------------
def _stats(values: list[float]) -> dict:
    v = [float(x) for x in values if x is not None]
    return {"mean": float(np.mean(v)) if v else None, "max": float(np.max(v)) if v else None}


def summarize(store: CampaignStore, campaign_id: int, *, truth: bool = False) -> dict:
    """The campaign summary over every recorded run (all sessions), from the database.

    Errors are the measured reflected-beam pointing errors, or with ``truth`` (simulation) the
    simulated truth. ``heliostats_per_hour``: recorded runs per plant hour, from the first run's
    start to the last run's end (plant clock); ``pipelined_speedup``: the sum of every run's own
    slew-to-standby and target time (what one-after-another would take) over that span.
    ``failed`` counts every run not calibrated (faults and runs out of iterations).
    """
    runs = store.runs(campaign_id)
    n_queue = len(json.loads(store.campaign(campaign_id)["queue_json"]))
    before = "true_error_before_mrad" if truth else "error_before_mrad"
    after = "true_error_after_mrad" if truth else "error_after_mrad"
    calibrated = [r for r in runs if r["status"] == "calibrated"]
    occ = [r["off_target_s"] - r["on_target_s"] for r in runs
           if r["off_target_s"] is not None and r["on_target_s"] is not None]
    span = (max(r["end_s"] for r in runs) - min(r["start_s"] for r in runs)) if runs else 0.0
    seq = sum(_sequential_share(r) for r in runs)
    return {
        "heliostats": n_queue,
        "calibrated": len(calibrated),
        "failed": len(runs) - len(calibrated),
        "error_before_mrad": _stats([r[before] for r in runs]),
        "error_after_mrad": _stats([r[after] for r in runs]),
        "iterations_mean": float(np.mean([r["iterations"] for r in runs])) if runs else None,
        "target_occupancy_s_mean": float(np.mean(occ)) if occ else None,
        "heliostats_per_hour": 3600.0 * len(runs) / span if span > 0 else None,
        "pipelined_speedup": seq / span if span > 0 else None,
    }
