"""What one calibration cycle talks to: the heliostat's geometry (:class:`Pointing`), its
drive and camera, the measurement chain, the target gate and an observer (:class:`CycleContext`).

Units: motor steps (int), ENU metres, plant-clock seconds; per-state timeouts in wall seconds.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from controller.calibration.cycle.gate import TargetGate
from controller.calibration.cycle.observations import Observation, Step
from controller.calibration.records import MeasurementRecord, ModelRecord
from controller.devices.plant_time import WALL, PlantTime
from controller.recognition.library import Match


class Pointing(Protocol):
    """Geometry of one heliostat (:class:`controller.calibration.cycle.pointing.GeometryPointing`)."""

    heliostat_pos: np.ndarray
    aim_point: np.ndarray
    source_dir: np.ndarray
    source_pos: tuple[float, float, float] | None  # a lamp's position (None: the sun)

    def aim_steps(self, model: ModelRecord | None) -> tuple[int, int]: ...
    def standby_steps(self, model: ModelRecord | None) -> tuple[int, int]: ...
    def leave_steps(self, model: ModelRecord | None, seen=None) -> tuple[int, int]: ...
    def path_to(self, start: tuple[int, int], end: tuple[int, int]) -> list[tuple[int, int]]: ...
    def stay_margin_m(self) -> float: ...
    def view_margin_m(self) -> float | np.ndarray: ...
    def path_margin_m(self) -> float | np.ndarray: ...
    def off_targets(self, az_steps: float, el_steps: float, margin_m=2.0) -> bool: ...
    def beam_on_target(self, az_steps: float, el_steps: float, margin_m: float = 2.0) -> bool: ...
    def may_wait_at(self, pose: tuple[int, int], standby: tuple[int, int], aim: tuple[int, int],
                    margin_m: float) -> bool: ...
    def fine_correction(self, az_steps: int, el_steps: int, offset_enu: np.ndarray) -> Step: ...
    def coarse_correction(self, az_steps: int, el_steps: int, daz_deg: float, del_deg: float) -> Step: ...
    def fit(self, measurements: list[MeasurementRecord], prior: ModelRecord | None) -> ModelRecord | None: ...


@dataclass
class CycleContext:
    """Everything one cycle talks to. ``drive`` and ``camera`` are the real interfaces."""

    heliostat_id: str
    queue_index: int
    drive: Any  # controller.devices.drive.Drive
    camera: Any  # controller.devices.camera.DoubleCcdCamera
    pointing: Pointing
    merge: Callable[[Any], np.ndarray]  # FramePair -> HDR float image
    analyze: Callable[[np.ndarray], Observation]  # raises BeamNotFound
    match: Callable[[Observation], Match | None]  # its shape -> the library's Match, None without one
    gate: TargetGate
    model: ModelRecord | None = None  # fitted tracking-error parameters from earlier runs
    history: list[MeasurementRecord] = field(default_factory=list)  # earlier measurements
    tolerance_mrad: float = 0.5
    max_iterations: int = 4
    settle_s: float = 0.5
    move_timeout_s: float = 120.0  # plant seconds
    time: PlantTime = WALL  # plant time: waits, deadlines, stamps, the controller's computing
    timeouts: dict[str, float] = field(default_factory=dict)  # per-state overrides, wall s
    save_images: Callable[[Any, np.ndarray, int], list] | None = None  # -> [ImageRecord]
    observer: CycleObserver | None = None  # told of state changes and measurements
    ticket: int | None = None  # turn on the target (TargetGate); default: queue_index
    observe_only: bool = False  # a planned observation: one measurement, no correction
    coarse_confidence: float | None = None  # apply a match's coarse correction at >= this; None: never
    backlash_steps: tuple[int, int] = (0, 0)  # (az, el): measuring moves end moving up by more
    group: Any = None  # several beams on the target: controller.calibration.beams.group.SharedCapture


class CycleObserver:
    """What a cycle tells the outside world; every hook defaults to doing nothing.

    A user interface follows the states; a simulation harness reads its own truth at each
    measurement. Hooks run on the cycle's thread and must return quickly."""

    def state_changed(self, heliostat_id: str, state: str) -> None:
        """The cycle of ``heliostat_id`` entered ``state``."""

    def measured(self, heliostat_id: str, measurement: MeasurementRecord) -> None:
        """A measurement was taken (the beam is on the target at the measured pose)."""
