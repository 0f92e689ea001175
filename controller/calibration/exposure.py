"""Auto-exposure in the loop: capture, decide (:func:`controller.imaging.autoexposure.next_exposures`),
set, repeat."""

from __future__ import annotations

from dataclasses import dataclass

from controller.devices.camera import DoubleCcdCamera
from controller.imaging.autoexposure import ExposureStep, next_exposures


@dataclass(frozen=True)
class AutoExposureResult:
    exposures: tuple[float, float]
    converged: bool
    steps: tuple[ExposureStep, ...]


def auto_expose(camera: DoubleCcdCamera, *, max_steps: int = 12, bit_depth: int = 8,
                dark_offset: float = 8.0, useful_fraction: float = 0.5, max_saturated: int = 0,
                step: float = 2.0, limits_s: tuple[float, float] = (1e-5, 1.0)) -> AutoExposureResult:
    """Capture, decide, set, repeat until a pair needs no change (or ``max_steps`` pairs)."""
    steps = []
    for _ in range(max_steps):
        pair = camera.capture()
        decision = next_exposures(pair.low, pair.high, camera.exposures, bit_depth=bit_depth,
                                  dark_offset=dark_offset, useful_fraction=useful_fraction,
                                  max_saturated=max_saturated, step=step, limits_s=limits_s)
        steps.append(decision)
        if decision.action == "ok":
            return AutoExposureResult(camera.exposures, True, tuple(steps))
        camera.set_exposures(*decision.exposures)
    return AutoExposureResult(camera.exposures, False, tuple(steps))
