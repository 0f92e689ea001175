"""Campaign throughput on the embedded simulated plant: pipelined vs one heliostat after another.

Runs ``heliocal demo`` twice with the same seed (pipelined, then ``--sequential``) into temporary
directories and prints JSON: heliostats per hour (plant time) of each, their measured ratio,
the pipelined run's own ``pipelined_speedup`` estimate, and the wall time of each run.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

N = 12


def run(out: Path, *extra: str) -> tuple[dict, float]:
    t0 = time.perf_counter()
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "controller.cli",
            "demo",
            "--heliostats",
            str(N),
            "--out",
            str(out),
            "--json",
            *extra,
        ],
        capture_output=True,
        text=True,
    )
    if r.returncode not in (0, 3):  # 3: a night ended partial; the demo still ran to its end
        raise SystemExit(f"bench_campaign: heliocal demo exited {r.returncode}: {r.stderr.strip()[-400:]}")
    return json.loads(r.stdout), time.perf_counter() - t0


def main() -> None:
    with tempfile.TemporaryDirectory() as d:
        pipe, wall_p = run(Path(d) / "pipelined")
        seq, wall_s = run(Path(d) / "sequential", "--sequential")
    print(
        json.dumps(
            {
                "heliostats": N,
                "pipelined_heliostats_per_hour": pipe["heliostats_per_hour"],
                "sequential_heliostats_per_hour": seq["heliostats_per_hour"],
                "measured_speedup": pipe["heliostats_per_hour"] / seq["heliostats_per_hour"],
                "estimated_speedup": pipe["pipelined_speedup"],
                "pipelined_error_after_max_mrad": pipe["error_after_mrad"]["max"],
                "sequential_error_after_max_mrad": seq["error_after_mrad"]["max"],
                "wall_s_pipelined": wall_p,
                "wall_s_sequential": wall_s,
            }
        )
    )


if __name__ == "__main__":
    main()
