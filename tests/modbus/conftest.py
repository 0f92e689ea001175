"""Fixtures: simulated drive controllers behind a ModbusSimServer, and drives talking to it.

The controllers run on a clock 20x faster than real time (like the demo plant), so moves
of a few thousand steps finish in a fraction of a second without mocking time away."""

from __future__ import annotations

import time

import pytest

from controller.devices.drive import AxisLimits, DriveLimits
from controller.devices.modbus_drive import ModbusDrive, ModbusLink
from simplant.firmware.modbus import ModbusSimServer
from simplant.firmware.physics import AxisParams, SimController
from tests.conftest import scaled_s

SPEEDUP = 20.0
# Demo plant (configs/demo.yaml): hard range [0, 75308] / [0, 68745], soft limits below.
LIMITS = DriveLimits(AxisLimits(500, 74800), AxisLimits(500, 68200))


def fast_clock(speedup: float = SPEEDUP):
    t0 = time.monotonic()
    return lambda: t0 + speedup * (time.monotonic() - t0)


def make_controller(unit: int, start: tuple[int, int] = (500, 500)) -> SimController:
    return SimController(
        unit,
        AxisParams(500, 74800, 0, 75308, speed=1540.0, acceleration=3000.0, backlash=12),
        AxisParams(500, 68200, 0, 68745, speed=1540.0, acceleration=3000.0, backlash=12),
        clock=fast_clock(), initial_steps=start)


@pytest.fixture
def controllers() -> dict[int, SimController]:
    return {1: make_controller(1), 2: make_controller(2, (1000, 2000))}


@pytest.fixture
def sim(controllers):
    server = ModbusSimServer(controllers)
    server.port = server.start_tcp()
    yield server
    server.stop()


@pytest.fixture
def link(sim):
    lk = ModbusLink.tcp("127.0.0.1", sim.port, timeout_s=scaled_s(0.5), retries=1)
    yield lk
    lk.close()


@pytest.fixture
def drive(link) -> ModbusDrive:
    return ModbusDrive(link, 1, LIMITS)


@pytest.fixture
def raw_client(sim):
    """A plain pymodbus client (no retries) for wire-level checks of the simulated device."""
    from pymodbus.client import ModbusTcpClient

    client = ModbusTcpClient("127.0.0.1", port=sim.port, timeout=scaled_s(0.5), retries=0)
    yield client
    client.close()
