"""Modbus link speed: status polls per second against ModbusSimServer.

``modbus_tcp_polls_per_s`` is imported by ``benchmarks/bench_link.py``; run this file on its
own for the Modbus numbers alone::

    .venv/bin/python benchmarks/_modbus_bench.py [--seconds 2]

One poll is one ``ModbusDrive.status()``: a single read of input registers 0-11 and its
decoding, over loopback TCP (or the pty null modem for RTU), client and server in one process.
"""

from __future__ import annotations

import argparse
import json
import time

from controller.devices.drive import AxisLimits, DriveLimits
from controller.devices.modbus_drive import ModbusDrive, ModbusLink
from simplant.firmware.modbus import ModbusSimServer
from simplant.firmware.physics import AxisParams, SimController

_LIMITS = DriveLimits(AxisLimits(500, 74800), AxisLimits(500, 68200))


def _controller() -> SimController:
    return SimController(1, AxisParams(500, 74800, 0, 75308), AxisParams(500, 68200, 0, 68745))


def _polls_per_s(drive: ModbusDrive, seconds: float) -> float:
    drive.status()  # connect / open before timing
    n, t0 = 0, time.perf_counter()
    while (elapsed := time.perf_counter() - t0) < seconds:
        drive.status()
        n += 1
    return n / elapsed


def modbus_tcp_polls_per_s(seconds: float = 2.0) -> float:
    """Status polls per second of one ModbusDrive against ModbusSimServer over loopback TCP."""
    with ModbusSimServer({1: _controller()}) as sim:
        link = ModbusLink.tcp("127.0.0.1", sim.start_tcp())
        try:
            return _polls_per_s(ModbusDrive(link, 1, _LIMITS), seconds)
        finally:
            link.close()


def modbus_rtu_polls_per_s(seconds: float = 2.0, baud: int = 115200) -> float:
    """The same over Modbus RTU on the simulator's pty (no real baud-rate delay on a pty)."""
    with ModbusSimServer({1: _controller()}) as sim:
        link = ModbusLink.rtu(sim.start_rtu(baud=baud), baud)
        try:
            return _polls_per_s(ModbusDrive(link, 1, _LIMITS), seconds)
        finally:
            link.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=2.0, help="duration of each measurement")
    args = ap.parse_args()
    print(json.dumps({"modbus_tcp_polls_per_s": round(modbus_tcp_polls_per_s(args.seconds), 1),
                      "modbus_rtu_polls_per_s": round(modbus_rtu_polls_per_s(args.seconds), 1),
                      "seconds": args.seconds}))


if __name__ == "__main__":
    main()
