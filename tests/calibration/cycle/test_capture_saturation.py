"""The campaign's capture: a beam core saturated in both sensors is taken again, shorter."""

from __future__ import annotations

import numpy as np

from controller.calibration.cycle.exposure import RECAPTURES, capture_unsaturated, saturated_both
from controller.devices.camera import DoubleCcdCamera, FramePair


class _Camera(DoubleCcdCamera):
    """A spot whose counts scale with exposure; 8-bit sensors clip at 255."""

    def __init__(self, peak_counts_per_s: float) -> None:
        self.rate = peak_counts_per_s
        self._exp = (0.010, 0.020)
        self.taken: list[tuple[float, float]] = []
        yy, xx = np.mgrid[0:40, 0:40]
        self.shape = np.exp(-((xx - 20) ** 2 + (yy - 20) ** 2) / 50.0)

    @property
    def exposures(self):
        return self._exp

    def set_exposures(self, t_low, t_high):
        self._exp = (t_low, t_high)

    def capture(self):
        self.taken.append(self._exp)
        low, high = (np.clip(self.rate * t * self.shape, 0, 255).astype(np.uint8) for t in self._exp)
        return FramePair(low, high, self._exp, 0.0)


def test_saturated_core_is_recaptured_shorter_and_exposures_restored():
    cam = _Camera(peak_counts_per_s=80_000.0)  # LOW peak 800, 400, 200 counts at 10, 5, 2.5 ms
    pair = capture_unsaturated(cam, bit_depth=8)
    assert pair.metadata == {"saturated_px": 0, "recaptures": 2, "lengthened": 0}  # 10 → 5 → 2.5 ms
    assert pair.exposures == (0.0025, 0.005) and saturated_both(pair, 8) == 0
    assert cam.exposures == (0.010, 0.020)  # the next heliostat starts at the configured ones


def test_unsaturated_pair_is_taken_once():
    cam = _Camera(peak_counts_per_s=10_000.0)
    pair = capture_unsaturated(cam, bit_depth=8)
    assert pair.metadata["recaptures"] == 0 and len(cam.taken) == 1


def test_tries_are_bounded_and_the_count_is_reported():
    cam = _Camera(peak_counts_per_s=1e9)
    pair = capture_unsaturated(cam, bit_depth=8)
    assert len(cam.taken) == 1 + RECAPTURES
    assert pair.metadata["recaptures"] == RECAPTURES and pair.metadata["saturated_px"] > 0


def test_dim_beam_is_recaptured_longer_until_bright_enough_and_exposures_restored():
    cam = _Camera(peak_counts_per_s=1_000.0)  # HIGH peak 20 counts at 20 ms: 8 % of full scale
    pair = capture_unsaturated(cam, bit_depth=8)
    # 20 → 40 → 80 ms: the HIGH peak 80 counts is over a quarter of full scale.
    assert pair.metadata["lengthened"] == 2 and pair.exposures == (0.040, 0.080)
    assert np.max(pair.high) >= 0.25 * 255 and saturated_both(pair, 8) == 0
    assert cam.exposures == (0.010, 0.020)


def test_a_dim_beam_is_never_lengthened_into_saturation_nor_forever():
    cam = _Camera(peak_counts_per_s=0.0)  # nothing in view: bounded tries
    pair = capture_unsaturated(cam, bit_depth=8)
    assert pair.metadata["lengthened"] == 5 and len(cam.taken) == 6
    cam = _Camera(peak_counts_per_s=3_000.0)  # HIGH 60 counts: doubled once to 120 (LOW 60)
    pair = capture_unsaturated(cam, bit_depth=8)
    assert pair.metadata["lengthened"] == 1 and saturated_both(pair, 8) == 0
