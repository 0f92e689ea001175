"""Status round trips per second over a pty, with the simulated firmware in another process.

Runs ``heliocal sim firmware --serial-link`` as a child process, then times GET_STATUS
exchanges through :class:`controller.devices.serial_drive.SerialDrive` (the full software
path: encode, write, select/read, decode, CRC, dataclass). A pty has no baud-rate delay, so
this measures software overhead only; target >= 2,000/s (<= 0.5 ms per exchange). Also
reports Modbus TCP status polls per second via benchmarks/bench_modbus.py.

Usage: .venv/bin/python benchmarks/bench_link.py [--seconds S]   (prints one JSON object)
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from controller.devices.drive import AxisLimits, DriveLimits  # noqa: E402
from controller.devices.serial_drive import SerialBus, SerialDrive  # noqa: E402

TARGET_PER_S = 2000.0


def serial_round_trips(seconds: float) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        link = Path(tmp) / "bus"
        proc = subprocess.Popen(
            [sys.executable, "-m", "controller.cli", "sim", "firmware", "--serial-link", str(link),
             "--units", "1", "--config", str(ROOT / "configs" / "demo.yaml"), "--json"],
            stdout=subprocess.PIPE, text=True, cwd=ROOT)
        try:
            json.loads(proc.stdout.readline())
            bus = SerialBus(str(link), timeout_s=0.2, retries=3)
            drive = SerialDrive(bus, 1, DriveLimits(AxisLimits(0, 1), AxisLimits(0, 1)))
            for _ in range(200):  # warm-up: session PING, caches, scheduler
                drive.status()
            lat = []
            end = time.perf_counter() + seconds
            while True:
                t = time.perf_counter()
                if t >= end:
                    break
                drive.status()
                lat.append(time.perf_counter() - t)
            bus.close()
        finally:
            proc.terminate()
            proc.wait(5)
    n = len(lat)
    total = sum(lat)
    q = statistics.quantiles(lat, n=100)
    return {"serial_status_round_trips_per_s": round(n / total, 1), "serial_exchanges": n,
            "serial_round_trip_ms": {"mean": round(1e3 * total / n, 4), "p50": round(1e3 * q[49], 4),
                                     "p99": round(1e3 * q[98], 4)},
            "serial_round_trips_per_s_at_p50": round(1.0 / q[49], 1),
            "serial_retries": drive.retries_used, "target_per_s": TARGET_PER_S,
            "meets_target": n / total >= TARGET_PER_S}


def modbus_polls() -> dict:
    path = ROOT / "benchmarks" / "bench_modbus.py"
    if not path.exists():
        return {"modbus_tcp_status_polls_per_s": None, "modbus_note": "benchmarks/bench_modbus.py missing"}
    try:
        spec = importlib.util.spec_from_file_location("bench_modbus", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return {"modbus_tcp_status_polls_per_s": module.modbus_tcp_polls_per_s()}
    except Exception as exc:  # report, don't hide, a broken Modbus benchmark
        return {"modbus_tcp_status_polls_per_s": None, "modbus_note": f"{type(exc).__name__}: {exc}"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="measuring time (default 3 s)")
    args = parser.parse_args()
    # The tail (p99) is scheduling of the two processes: report the load it was measured under.
    load = {"load_average_1min": round(os.getloadavg()[0], 2), "cpus": os.cpu_count()}
    print(json.dumps({"benchmark": "bench_link", **serial_round_trips(args.seconds), **modbus_polls(),
                      **load}))


if __name__ == "__main__":
    main()
