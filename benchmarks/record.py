"""Record what a benchmark (or any command printing one JSON object) measured, as the source of
the figures the docs quote.

    python benchmarks/record.py NAME -- python benchmarks/bench_planner.py
    python benchmarks/record.py demo-seed0 -- heliocal demo --json --seed 0
    python benchmarks/record.py make-demo -- make demo

Runs the command in the repository's root (a leading ``python`` or ``heliocal`` is this
interpreter's, i.e. the project's .venv), its standard error passed through, and writes
``benchmarks/results/NAME.json``:

* ``output``: what the command printed on standard output, when that is one JSON object
  (else null: ``make demo`` is recorded for its time only);
* ``command``, ``exit`` (0, or 3 for a run that ended ``partial``: anything else writes nothing),
  ``commit`` (and ``dirty`` when the worktree had changes outside benchmarks/results), the
  UTC time it started;
* ``wall_s``, ``cpu_s`` (user + system of the command's processes), ``load_average``
  (1-min, before and after) and ``cores``: the machine is shared, and the load says how much.

``docs/results.md`` and the README mark every figure they take from such a file
(``<!--fig NAME KEY-->``, see ``benchmarks/figures.py``); ``tests/test_doc_figures.py`` fails
when a marked figure disagrees with its file. Benchmarks are never run by the test suite.
"""

from __future__ import annotations

import datetime as dt
import json
import os
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
NAME = re.compile(r"[a-z0-9][a-z0-9-]*")
OK_EXITS = (0, 3)  # 3: ran to its end, some heliostats or geometries not measured (docs/cli.md)


def resolve(command: list[str]) -> list[str]:
    """``command`` with a leading ``python`` / ``heliocal`` taken from this interpreter's
    environment, so that a recording uses the project's .venv whatever the shell's PATH."""
    head, *rest = command
    if head in ("python", "python3"):
        return [sys.executable, *rest]
    local = Path(sys.executable).parent / head
    return [str(local), *rest] if head == "heliocal" and local.is_file() else command


def git(*args: str) -> str:
    p = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)
    return p.stdout.strip() if p.returncode == 0 else ""


def parse_output(text: str) -> dict | list | None:
    """The command's standard output as JSON: the whole of it, else its last line (a command
    that prints progress first), else None."""
    for candidate in (text, text.strip().rsplit("\n", 1)[-1]):
        try:
            return json.loads(candidate)
        except ValueError:
            continue
    return None


def record(name: str, command: list[str]) -> Path:
    """Run ``command`` and write ``benchmarks/results/<name>.json`` (module docstring)."""
    started = dt.datetime.now(dt.UTC).replace(microsecond=0).isoformat()
    load_before = os.getloadavg()[0]
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run(resolve(command), cwd=ROOT, stdout=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode not in OK_EXITS:
        sys.exit(f"record.py: {' '.join(command)} exited {p.returncode}; nothing written\n{p.stdout[-2000:]}")
    changed = [line for line in git("status", "--porcelain").splitlines()
               if not line[3:].startswith("benchmarks/results/")]
    data = {"command": " ".join(command), "exit": p.returncode,
            "commit": git("rev-parse", "--short=12", "HEAD"),
            "dirty": bool(changed), "started_utc": started, "wall_s": round(wall, 1),
            "cpu_s": round(cpu1.ru_utime + cpu1.ru_stime - cpu0.ru_utime - cpu0.ru_stime, 1),
            "load_average": [round(load_before, 2), round(os.getloadavg()[0], 2)], "cores": os.cpu_count(),
            "output": parse_output(p.stdout)}
    RESULTS.mkdir(exist_ok=True)
    dest = RESULTS / f"{name}.json"
    tmp = dest.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    os.replace(tmp, dest)
    return dest


def main(argv: list[str]) -> int:
    if len(argv) < 3 or argv[1] != "--" or not NAME.fullmatch(argv[0]):
        print("usage: python benchmarks/record.py NAME -- COMMAND [ARGS...]  (NAME: a-z, 0-9, -)",
              file=sys.stderr)
        return 2
    dest = record(argv[0], argv[2:])
    print(f"record.py: wrote {dest.relative_to(ROOT)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
