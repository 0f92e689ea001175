"""The double-CCD camera interface.

A prism camera with two sensors sees the same scene at the same instant; sensor 0 has the
shorter exposure (LOW), sensor 1 the longer (HIGH). Implementations: ``FileCamera`` (replays
a manifest) and ``SimulatedCamera`` (renders the simulated plant), both in this package.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from controller.errors import DeviceError


class CameraError(DeviceError):
    """The camera failed to deliver a frame pair."""


@dataclass(frozen=True)
class FramePair:
    """One simultaneous capture. ``low``/``high``: 2-D uint8 (or uint16) arrays, shape (rows, cols);
    ``exposures``: (t_low, t_high) in seconds; ``timestamp``: seconds (camera clock)."""

    low: np.ndarray
    high: np.ndarray
    exposures: tuple[float, float]
    timestamp: float
    metadata: dict = field(default_factory=dict)


class DoubleCcdCamera(ABC):
    @abstractmethod
    def capture(self) -> FramePair: ...

    @abstractmethod
    def set_exposures(self, t_low: float, t_high: float) -> None: ...

    @property
    @abstractmethod
    def exposures(self) -> tuple[float, float]: ...

    def close(self) -> None:  # noqa: B027 - optional hook, most cameras hold nothing
        """Release the device."""
