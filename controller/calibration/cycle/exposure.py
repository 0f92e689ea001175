"""Exposure in the loop: auto-exposure (capture, decide with
:func:`controller.imaging.autoexposure.next_exposures`, set, repeat) and the campaign's
capture that will not measure a beam whose core saturates both sensors."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from controller.devices.camera import DoubleCcdCamera, FramePair
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


RECAPTURES = 3  # shorter exposures tried before a saturated pair is handed on as it is
# A beam too dim to measure well — a far heliostat's spot is spread over metres, so its peak is
# a fraction of a near one's — is taken again with longer exposures: while the HIGH frame's
# brightest pixel is below DIM_FRACTION of full scale, both exposures are doubled, LENGTHENS
# times at most and never into a pair that saturates both sensors.
DIM_FRACTION = 0.25
LENGTHENS = 5


def saturated_both(pair: FramePair, bit_depth: int) -> int:
    """Pixels at full scale in the LOW (shorter) exposure, hence in both sensors: their merged
    value is only a lower bound."""
    low, full = np.asarray(pair.low), (1 << bit_depth) - 1
    if low.max(initial=0) < full:  # the common case, without a mask of the whole frame
        return 0
    return int(np.count_nonzero(low >= full))


def _dim(pair: FramePair, bit_depth: int) -> bool:
    return float(np.max(pair.high)) < DIM_FRACTION * ((1 << bit_depth) - 1)


def capture_unsaturated(camera: DoubleCcdCamera, *, bit_depth: int, factor: float = 0.5,
                        min_exposure_s: float = 1e-5, max_exposure_s: float = 1.0) -> FramePair:
    """A pair whose beam saturates no pixel in both sensors and is not too dim: when the LOW
    exposure has saturated pixels, both exposures are shortened by ``factor`` and the pair is
    taken again, :data:`RECAPTURES` times at most; when nothing saturates and the beam is dim
    (:data:`DIM_FRACTION`), they are lengthened by 1/``factor`` instead, :data:`LENGTHENS`
    times at most. The camera's exposures are restored afterwards. The pair's metadata records
    ``saturated_px`` (of the pair returned), ``recaptures`` and ``lengthened``."""
    start = camera.exposures
    pair = camera.capture()
    n, tries, longer = saturated_both(pair, bit_depth), 0, 0
    try:
        while n and tries < RECAPTURES and min(camera.exposures) * factor >= min_exposure_s:
            camera.set_exposures(*(t * factor for t in camera.exposures))
            pair = camera.capture()
            n, tries = saturated_both(pair, bit_depth), tries + 1
        while (not n and not tries and longer < LENGTHENS and _dim(pair, bit_depth)
               and max(camera.exposures) / factor <= max_exposure_s):
            camera.set_exposures(*(t / factor for t in camera.exposures))
            trial = camera.capture()
            if saturated_both(trial, bit_depth):
                break  # one step too long: the previous pair is the one to measure
            pair, longer = trial, longer + 1
    finally:
        if tries or longer:
            camera.set_exposures(*start)
    return replace(pair, metadata={**pair.metadata, "saturated_px": n, "recaptures": tries,
                                   "lengthened": longer})
