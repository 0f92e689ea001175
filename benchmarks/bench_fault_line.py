"""Jogs through a noisy serial line: is any jog executed twice, or lost without a word?

1,000 jogs (default) from a :class:`SerialDrive` to the simulated firmware through a
:class:`simplant.devices.noisy_line.NoisyLine` that flips, drops and duplicates 0.3 % of the bytes
(each, per byte) and delays some chunks. After every jog the line is let drain, then the
firmware's own log says how often that jog was executed. Prints JSON counts:

* ``executed_once``: reported OK, executed once;
* ``executed_twice``: executed more than once (must be 0);
* ``silent_losses``: reported OK but not executed (must be 0);
* ``outcome_unknown``: no valid answer (``LinkError``, outcome ``unknown``), with how many of
  those the firmware did execute;
* ``clear_failures``: refused or failed with a known outcome.

Usage: .venv/bin/python benchmarks/bench_fault_line.py [--jogs N] [--p P] [--seed S]
"""

from __future__ import annotations

import argparse
import json
import time

from controller.devices.drive import AxisLimits, DriveError, DriveLimits, LinkError
from controller.devices.serial_drive import SerialBus, SerialDrive
from simplant.devices.noisy_line import NoisyLine
from simplant.firmware.physics import AxisParams, SimController
from simplant.firmware.serial import SerialSimFirmware

LIMITS = DriveLimits(AxisLimits(500, 74800), AxisLimits(500, 68200))


def run(jogs: int, p: float, seed: int) -> dict:
    axis = AxisParams(500, 74800, 0, 75308, speed=1540.0, acceleration=3000.0)
    ctl = SimController(1, axis, AxisParams(**{**axis.__dict__}))
    fw = SerialSimFirmware({1: ctl})
    fw.start()
    max_delay = 0.004
    line = NoisyLine(fw.device, seed, flip=p, drop=p, dup=p, delay=0.05, max_delay_s=max_delay)
    bus = SerialBus(line.device, timeout_s=0.03, retries=3)
    drive = SerialDrive(bus, 1, LIMITS)
    counts = {"jogs": jogs, "executed_once": 0, "executed_twice": 0, "silent_losses": 0,
              "outcome_unknown": 0, "outcome_unknown_executed": 0, "clear_failures": 0}
    t0 = time.perf_counter()
    try:
        for i in range(jogs):
            before = sum(e.command == "JOG" for e in ctl.log)
            step = 1 if i % 2 == 0 else -1  # stays inside the limits, every jog a distinct request
            ok, unknown = False, False
            try:
                drive._send_jog(step, 0)
                ok = True
            except LinkError as exc:
                unknown = exc.outcome == "unknown"
                if not unknown:
                    counts["clear_failures"] += 1
            except DriveError:
                counts["clear_failures"] += 1
            time.sleep(2 * max_delay)  # let the line drain: late bytes belong to this jog
            executed = sum(e.command == "JOG" for e in ctl.log) - before
            if executed > 1:
                counts["executed_twice"] += 1
            elif ok:
                counts["executed_once" if executed == 1 else "silent_losses"] += 1
            elif unknown:
                counts["outcome_unknown"] += 1
                counts["outcome_unknown_executed"] += executed
    finally:
        bus.close()
        line.close()
        fw.stop()
    counts["line"] = dict(line.counts)
    counts["retransmissions"] = bus.retries_used
    counts["wall_s"] = round(time.perf_counter() - t0, 2)
    return counts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jogs", type=int, default=1000, help="jogs to send (default 1000)")
    ap.add_argument("--p", type=float, default=0.003,
                    help="per-byte flip/drop/dup probability (default 0.003)")
    ap.add_argument("--seed", type=int, default=0, help="line noise seed (default 0)")
    args = ap.parse_args()
    print(json.dumps({"benchmark": "bench_fault_line", **run(args.jogs, args.p, args.seed)}))


if __name__ == "__main__":
    main()
