"""Beam safety as the plant's truth sees it: whose reflected central ray is on each target."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from controller.geometry.vectors import unit
from simplant.devices.grids import camera_grid
from simplant.poses import PlantTruth, true_pose


class WatchedPlant(PlantTruth, Protocol):
    """What the monitor watches (:class:`simplant.plant.SimulatedPlant`, which owns its monitor,
    is one): the configuration, the plant clock, the lit lamp and each heliostat's true normal."""

    cfg: Any  # controller.config.PlantConfig
    clock: Callable[[], float]

    def lamp(self) -> Any: ...

    def true_normal(self, hid: str) -> np.ndarray: ...


class BeamSafetyMonitor:
    """Watches the plant's truth: whose reflected central ray is on each target right now.

    Samples every ``period_s`` of wall time; ``violations`` counts the (sample, target) pairs
    with more beams on the target than the lit source allows (the controller must never cause
    one): one beam of concentrated *sunlight*, ``calibration.beams_per_target`` beams of a
    *lamp* (weak at night, docs/campaigns.md); ``report()`` summarises;
    ``intervals`` lists, per target, the plant-clock spans (start, end, heliostat) during
    which one beam was on it."""

    def __init__(self, plant: WatchedPlant, period_s: float = 0.02) -> None:
        self.plant = plant
        self.period_s = period_s
        self.samples = 0
        self.violations = 0
        self.max_on_target = 0
        self.offenders: set[tuple[str, ...]] = set()
        self.intervals: dict[str, list[tuple[float, float, str]]] = {}
        self._open: dict[str, tuple[float, str]] = {}
        self._frames: dict[str, tuple] = {}  # target id -> centre, normal, u, v (_target_frame)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def on_target(self, target: str | None = None, beams: dict | None = None) -> list[str]:
        """The heliostats whose true reflected central ray lands on ``target`` (default: the
        calibration target) now; ``beams`` (:meth:`beams`) when the caller has them."""
        p = self.plant
        tgt = p.cfg.target(target)
        if p.lamp() is None:
            return []  # dark: no beam anywhere
        c, nrm, u_axis, v_axis = self._target_frame(tgt.id)
        out = []
        for hid, (pos, beam) in (self.beams() if beams is None else beams).items():
            den = float(nrm @ beam)
            if abs(den) < 1e-9:
                continue
            t = float(nrm @ (c - pos)) / den
            if t <= 0:
                continue
            rel = pos + t * beam - c
            if abs(rel @ u_axis) <= tgt.width_m / 2 and abs(rel @ v_axis) <= tgt.height_m / 2:
                out.append(hid)
        return out

    def beams(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Per heliostat: its true mirror centre and the reflection r = 2 (s·n) n − s of the lit
        lamp's direction s about its true normal n (one read of the rods for every target)."""
        p = self.plant
        if p.lamp() is None:
            return {}  # every lamp dark: no beam
        lamp = np.asarray(p.lamp().position_enu_m, float)
        out = {}
        for hid in p.hidden:
            n, pos = true_pose(p, hid)
            s = unit(lamp - pos)
            out[hid] = (pos, 2.0 * (s @ n) * n - s)
        return out

    def _target_frame(self, target_id: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Centre, unit normal and the camera grid's u, v axes of a target (fixed: kept)."""
        frame = self._frames.get(target_id)
        if frame is None:
            p = self.plant
            tgt = p.cfg.target(target_id)
            base = camera_grid(p.cfg.for_target(target_id))
            frame = (np.asarray(tgt.center_enu_m, float), unit(np.asarray(tgt.normal, float)),
                     base.u_axis, base.v_axis)
            self._frames[target_id] = frame
        return frame

    def in_person_zones(self, reach_m: float = 400.0, step_m: float = 0.05) -> list[tuple[str, str]]:
        """(heliostat, zone id) pairs whose true reflected central ray passes through a person
        zone (config ``person_zones``, the bare boxes without their margins) now: points every
        ``step_m`` along the ray up to ``reach_m``, or up to a target it lands on."""
        p = self.plant
        lamp = p.lamp()
        if lamp is None or not p.cfg.person_zones:
            return []
        out = []
        for hid, hh in p.hidden.items():
            n = p.true_normal(hid)
            pos = hh.truth.mirror_center(*hh.controller.output_steps(), night=p.night)
            s = unit(np.asarray(lamp.position_enu_m, float) - pos)
            beam = 2.0 * (s @ n) * n - s
            end = reach_m
            for tgt in p.cfg.targets:
                c, nrm = np.asarray(tgt.center_enu_m, float), unit(np.asarray(tgt.normal, float))
                base = camera_grid(p.cfg.for_target(tgt.id))
                den = float(nrm @ beam)
                t = float(nrm @ (c - pos)) / den if abs(den) > 1e-9 else -1.0
                rel = pos + t * beam - c
                if 0 < t < end and abs(rel @ base.u_axis) <= tgt.width_m / 2 \
                        and abs(rel @ base.v_axis) <= tgt.height_m / 2:
                    end = t
            pts = pos + np.arange(0.0, end, step_m)[:, None] * beam
            for z in p.cfg.person_zones:
                if np.all((pts >= z.min_enu_m) & (pts <= z.max_enu_m), axis=1).any():
                    out.append((hid, z.id))
        return out

    def sample(self) -> None:
        """One look at every target (the monitor's thread calls this every ``period_s``)."""
        now = self.plant.clock()
        self.samples += 1
        beams = self.beams()
        allowed = self.allowed_beams()
        for t in self.plant.cfg.targets:
            on = self.on_target(t.id, beams)
            self.max_on_target = max(self.max_on_target, len(on))
            if len(on) > allowed:
                self.violations += 1
                self.offenders.add(tuple(sorted(on)))
            held = self._open.get(t.id)
            if held is not None and (len(on) != 1 or on[0] != held[1]):
                self.intervals.setdefault(t.id, []).append((held[0], now, held[1]))
                del self._open[t.id]
            if len(on) == 1 and t.id not in self._open:
                self._open[t.id] = (now, on[0])

    def allowed_beams(self) -> int:
        """Beams a target may hold now: ``calibration.beams_per_target`` under a lamp, one under
        the sun (and one while dark: any beam then is a fault of the simulation)."""
        src = self.plant.lamp()
        if src is not None and src.kind == "lamp":
            return self.plant.cfg.calibration.beams_per_target
        return 1

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self.sample()

    def start(self) -> None:
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="beam-safety", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        now = self.plant.clock()
        for tid, (start, hid) in self._open.items():
            self.intervals.setdefault(tid, []).append((start, now, hid))
        self._open.clear()

    def report(self) -> dict:
        return {"samples": self.samples, "violations": self.violations,
                "max_beams_on_target": self.max_on_target,
                "offenders": sorted(" + ".join(o) for o in self.offenders)}
