"""Fixtures of the imaging tests: sensor models, synthetic scenes with known irradiance."""

from __future__ import annotations

import numpy as np
import pytest

from controller.imaging.crf import Crf
from simplant.devices.sensor import SensorModel, knee_response


def synthetic_scene(h: int = 256, w: int = 256, peak: float = 60000.0) -> np.ndarray:
    """Known irradiance (counts/s): a Gaussian beam spot whose core saturates both sensors at
    10/20 ms, a sharp step edge, and a strip close to the dark offset."""
    y, x = np.mgrid[0:h, 0:w]
    e = peak * np.exp(-((x - 100.0) ** 2 + (y - 128.0) ** 2) / (2 * 25.0**2))
    e += np.where(x > 180, 6000.0, 300.0)
    e[:, :20] = 50.0
    return e


@pytest.fixture
def scene() -> np.ndarray:
    return synthetic_scene()


@pytest.fixture
def knee_sensor() -> SensorModel:
    return SensorModel(bit_depth=8, dark_offset=8.0, read_noise=0.8, full_well=20000.0,
                       response=knee_response(0.2))


@pytest.fixture
def knee_crf(knee_sensor) -> Crf:
    inv = knee_sensor.inverse_response()
    return Crf.from_tables([inv, inv])
