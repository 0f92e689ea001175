"""The adversarial cases of issue 27, counted by category (JSON on stdout).

    .venv/bin/python benchmarks/bench_adversarial.py

Per category: cases tried, refused cleanly (one InputError / exit 2 / HTTP 4xx naming the input,
nothing written), and the worst case's wall time (ms) and peak of Python-traced allocations
(MB, tracemalloc). The special files (FIFO, /dev/zero, folder, oversized) also run as real
``heliocal`` processes under a 1 GiB address-space limit (``RLIMIT_AS``), with their wall time
and peak RSS — the peer is what the same process did before (a FIFO blocked forever, /dev/zero
grew to 22 GB).

Categories: ``config_numbers`` (every numeric key of the schema × NaN, ±inf, ±1e308 and one
step past each bound), ``duplicate_keys`` (YAML and JSON), ``special_files`` (every bounded
reader × FIFO, folder, /dev/zero, oversized), ``cli_numbers`` (every numeric option × the same
values), ``console_bodies`` (oversized, nested, duplicate keys, not UTF-8, not JSON); then the
categories of each module of ``benchmarks/adversarial/`` (``tally.py`` says how they are written).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import importlib
import io
import json
import os
import pkgutil
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))
sys.path.insert(0, str(REPO))

from test_cli_numbers import OPTIONS, _bad_values  # noqa: E402
from test_config_ranges import KEYS, SOURCE, bad_values, holding, locate  # noqa: E402

from controller.config import load_config, parse_config  # noqa: E402
from controller.io.files import read_bytes  # noqa: E402
from controller.io.images import read_image  # noqa: E402
from controller.io.json_files import load_json, parse_json  # noqa: E402
from controller.io.yaml_files import load_yaml, parse_yaml  # noqa: E402

sys.path.insert(0, str(REPO / "benchmarks"))
from adversarial.tally import Tally, _input_error  # noqa: E402


def config_numbers() -> dict:
    t = Tally()
    for key in KEYS:
        for value in bad_values(key):
            doc = holding(key)
            container, index, path = locate(doc, key)
            container[index] = value
            t.case(f"{path}={value}", lambda d=doc: parse_config(d, SOURCE),
                   lambda o, p=path: _input_error(o) and f"{SOURCE}: {p}: " in str(o))
    return t.report()


def duplicate_keys() -> dict:
    t = Tally()
    yaml_cases = ["a: 1\na: 2\n", "x:\n  - {k: 1, k: 2}\n", "s: {a: 1}\ns: {b: 2}\n", "1: a\n1.0: b\n"]
    json_cases = ['{"a": 1, "a": 2}', '[{"k": 1,\n"k": 2}]', '{"k\\u0065y": 1, "key": 2}']
    def duplicate(o) -> bool:
        return _input_error(o) and "duplicate key" in str(o) and "first at line" in str(o)
    for text in yaml_cases:
        t.case(text, lambda s=text: parse_yaml(s, "f.yaml"), duplicate)
    for text in json_cases:
        t.case(text, lambda s=text: parse_json(s, "f.json"), duplicate)
    return t.report()


def special_files(folder: Path) -> tuple[dict, dict]:
    os.mkfifo(folder / "fifo")
    (folder / "folder").mkdir()
    (folder / "zero").symlink_to("/dev/zero")
    with open(folder / "oversized", "wb") as f:
        f.truncate((1 << 28) + (2 << 20))
    readers = {"yaml": load_yaml, "json": load_json, "image": read_image, "config": load_config,
               "bytes": read_bytes}
    t = Tally()
    for name in ("fifo", "folder", "zero", "oversized"):
        for reader in readers.values():
            p = folder / name
            t.case(name, lambda r=reader, p=p: r(p), lambda o, p=p: _input_error(o) and str(p) in str(o))
    procs = {}
    for name in ("fifo", "zero", "folder", "oversized"):
        argv = [sys.executable, "-c", _LIMITED, str(folder / name)]
        t0 = time.perf_counter()
        r = subprocess.run(argv, capture_output=True, text=True, timeout=60)
        rss = json.loads(r.stdout.strip().splitlines()[-1])["maxrss_mb"]
        procs[name] = {"exit": json.loads(r.stdout.strip().splitlines()[-1])["exit"],
                       "ms": round((time.perf_counter() - t0) * 1e3), "maxrss_mb": rss}
    return t.report(), procs


# ``heliocal sun --config FILE`` in a process limited to 1 GiB of address space; prints its
# exit status and peak RSS.
_LIMITED = """
import contextlib, io, json, resource, sys
resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))
from controller.cli import main
with contextlib.redirect_stderr(io.StringIO()):
    code = main(["sun", "--config", sys.argv[1], "--time", "2026-06-21T12:00:00Z"])
print(json.dumps({"exit": code, "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def cli_numbers() -> dict:
    from controller.cli import build_parser

    t = Tally()
    parser = build_parser()
    for path, action in OPTIONS:
        for value in _bad_values(action.type):
            values = [value] * (action.nargs if isinstance(action.nargs, int) else 1)

            def run(v=values, p=path, a=action):
                with contextlib.redirect_stderr(io.StringIO()) as err:
                    try:
                        parser.parse_args([*p, a.option_strings[0], *v])
                    except SystemExit as exc:
                        return exc.code, err.getvalue()
                return 0, ""
            t.case(f"{' '.join(path)} {action.option_strings[0]} {value}", run,
                   lambda o, a=action: isinstance(o, tuple) and o[0] == 2 and a.option_strings[0] in o[1])
    return t.report()


def console_bodies() -> dict:
    """The console's body reader on the same bodies as tests/console/test_api.py, through a
    minimal ASGI request (no plant needed: the bodies are refused before any handler)."""
    from starlette.requests import Request

    from controller.console.app import _bounded_json, _Refused

    bodies = [b"[" * 100_000 + b"]" * 100_000, b'{"a": ' * 5000 + b"1" + b"}" * 5000,
              b'{"k": 1, "k": 2}', b"\xff\xfe{}", b'{"az_steps": ', b" " * (1 << 20)]
    t = Tally()
    for body in bodies:
        async def call(b=body):
            sent = False

            async def receive():
                nonlocal sent
                if sent:
                    return {"type": "http.disconnect"}
                sent = True
                return {"type": "http.request", "body": b, "more_body": False}
            scope = {"type": "http", "method": "POST", "headers": [], "path": "/"}
            return await _bounded_json(Request(scope, receive))
        t.case(body[:20].decode("latin-1"), lambda c=call: asyncio.run(c()),
               lambda o: isinstance(o, _Refused) and 400 <= o.status < 500)
    return t.report()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        special, processes = special_files(Path(d))
        out = {"config_numbers": config_numbers(), "duplicate_keys": duplicate_keys(),
               "special_files": special, "special_files_as_processes_1GiB_limit": processes,
               "cli_numbers": cli_numbers(), "console_bodies": console_bodies()}
        for name in sorted(m.name for m in pkgutil.iter_modules([str(REPO / "benchmarks" / "adversarial")])):
            if name != "tally":
                out.update(importlib.import_module(f"adversarial.{name}").categories(Path(d)))
    cats = [v for v in out.values() if "tried" in v]
    out["total"] = {"tried": sum(c["tried"] for c in cats),
                    "refused_cleanly": sum(c["refused_cleanly"] for c in cats),
                    "worst_ms": max(c["worst_ms"] for c in cats),
                    "worst_peak_mb": max(c["worst_peak_mb"] for c in cats)}
    out["peak_rss_mb_this_process"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
