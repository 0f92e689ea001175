"""Fixtures for the serial link tests: fast simulated controllers, the firmware on a real pty,
and a fault-injecting pty proxy (the "noisy line") between the drive and the firmware."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from controller.devices.drive import AxisLimits, DriveLimits
from simplant.devices.noisy_line import NoisyLine
from simplant.firmware.physics import AxisParams, SimController
from simplant.firmware.serial import SerialSimFirmware

VECTORS = Path(__file__).resolve().parents[2] / "firmware_proto" / "vectors" / "frames.json"
SPEEDUP = 100.0  # plant clock vs. wall clock: a 10,000-step move takes ~0.07 s


@pytest.fixture(scope="session")
def vectors() -> dict:
    return json.loads(VECTORS.read_text())


def fast_clock(speedup: float = SPEEDUP):
    t0 = time.monotonic()
    return lambda: t0 + (time.monotonic() - t0) * speedup


def make_controller(unit: int, speedup: float = SPEEDUP, backlash: int = 12) -> SimController:
    """Axes like configs/demo.yaml (AA39 actuators), soft limits 500..74800 / 500..68200."""
    return SimController(
        unit,
        AxisParams(500, 74800, 0, 75308, speed=1540.0, acceleration=3000.0, backlash=backlash),
        AxisParams(500, 68200, 0, 68745, speed=1540.0, acceleration=3000.0, backlash=backlash),
        clock=fast_clock(speedup))


LIMITS = DriveLimits(AxisLimits(500, 74800), AxisLimits(500, 68200))


@pytest.fixture
def firmware():
    """The simulated firmware serving addresses 1 and 2 on a fresh pty."""
    fw = SerialSimFirmware({1: make_controller(1), 2: make_controller(2)})
    fw.start()
    yield fw
    fw.stop()


@pytest.fixture
def noisy_line_factory(firmware):
    lines = []

    def make(seed: int, **kw) -> NoisyLine:
        line = NoisyLine(firmware.device, seed, **kw)
        lines.append(line)
        return line

    yield make
    for line in lines:
        line.close()


@pytest.fixture
def limits() -> DriveLimits:
    return LIMITS


@pytest.fixture
def make_ctl():
    return make_controller
