"""``heliocal reprocess`` against a bad cluster or a bad archive (issue 45), for bench_adversarial.py.

Categories (each case is the whole command in this process, ``main([...])``, unless said):

* ``reprocess_not_a_scheduler``: ``--scheduler`` at peers that answer at once with something
  else — echo, random bytes, hang-ups, HTTP, an SSH banner, a length prefix of 1 TiB, garbled
  frames, bytes that are not msgpack, another Dask server's identity (tests/calibration/
  reprocess/peers.py) — and at a refused port and an unknown host: exit 1, one line naming the
  address, no output created;
* ``reprocess_silent_peers``: peers that never give a whole answer (silent, never accepting,
  a handshake then nothing, a byte every 50 ms, an HTTP server waiting for its request line)
  under ``--connect-timeout`` :data:`CONNECT_S`: exit 1 within it plus :data:`MARGIN_S`;
* ``reprocess_malformed_addresses``: exit 2 at once, nothing opened;
* ``reprocess_bad_frames``: the worker's own analysis of one pair
  (:func:`controller.calibration.reprocess.tasks.analyse_chunk`) whose LOW frame is a special
  file, oversized, truncated, garbled, of another size or format: the pair is ``unreadable``
  (or ``missing``), its reason naming the file;
* ``reprocess_bad_records``: the demo's records under an edited configuration or edited rows
  (heliostat, target or campaign gone, aim not finite, configuration file gone or special):
  exit 2, one line, no output created;
* ``reprocess_as_processes``: some of each as real ``heliocal`` processes (frames through a
  local cluster of one worker): exit status, wall time and peak RSS (the worst child's).

The archive is a demo run of the simulated plant at 256×192 (bench_reprocess's ``demo``).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import socket
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import yaml
from bench_reprocess import demo

from adversarial.tally import Tally
from controller.cli import main
from tests.calibration.reprocess.peers import NOT_SCHEDULERS, SILENT

CONNECT_S = 0.5  # --connect-timeout of the silent peers
MARGIN_S = 1.0  # what a refusal may take beyond it: the command's own parsing and checks, on a loaded machine


def _cli(argv: list[str]) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(argv)
    return code, err.getvalue()


def _one_line(code: int, *words: str):
    def ok(o) -> bool:
        if not isinstance(o, tuple):
            return False
        lines = o[1].strip().splitlines()
        return (o[0] == code and len(lines) == 1 and "Traceback" not in o[1]
                and all(w in lines[0] for w in words))
    return ok


def _scheduler_cases(folder: Path, peers: dict, timeout_s: float, slow_s: float | None) -> dict:
    """Each of ``peers`` (name → a context manager yielding its address) as ``--scheduler``."""
    source = folder / "empty.db"
    source.write_bytes(b"")
    t = Tally()
    for name, peer in peers.items():
        out = folder / "peer-out.db"
        with peer() as address:
            t0 = time.monotonic()
            argv = ["reprocess", "--db", str(source), "--out", str(out), "--scheduler", address,
                    "--connect-timeout", str(timeout_s)]
            t.case(name, lambda a=argv: _cli(a), _one_line(1, address))
            if slow_s is not None and time.monotonic() - t0 > slow_s:
                t.refused -= 1
                t.failures.append(f"{name}: took {time.monotonic() - t0:.2f} s")
        if out.exists():
            t.refused -= 1
            t.failures.append(f"{name}: {out} was created")
            out.unlink()
    return t.report()


@contextlib.contextmanager
def _at(peer):
    with peer() as port:
        yield f"tcp://127.0.0.1:{port}"


@contextlib.contextmanager
def _refused_port():
    with socket.create_server(("127.0.0.1", 0)) as s:
        port = s.getsockname()[1]  # closed: nothing listens there any more
    yield f"tcp://127.0.0.1:{port}"


@contextlib.contextmanager
def _unknown_host():
    yield "tcp://no-such-host.invalid:8786"


def addressed(peers: dict) -> dict:
    return {name: (lambda p=peer: _at(p)) for name, peer in peers.items()}


MALFORMED = ["tcp://" + "a" * 100_000 + ":8786", "tcp://" + "b" * 64 + ".example:8786", "tcp://a..b:8786",
             "tcp://-a:8786", "tcp://a b:8786", "tcp://127.0.0.1:0", "tcp://127.0.0.1:65536",
             "tcp://127.0.0.1:8786\n", "tcp://[1::2::3]:8786", "tcp://\u0661.\u0662:8786", "tcp://h\x00:1",
             "tcp://:8786", "tcp://host:", "TCP://host:8786", "udp://host:8786", "tcp://host:+80",
             "tls://127.0.0.1:8786", "", "tcp://host:8786/path", "tcp://user@host:8786"]


def malformed(folder: Path) -> dict:
    t = Tally()
    for address in MALFORMED:
        t.case(address[:40], lambda a=address: _cli(["reprocess", "--db", str(folder / "none.db"), "--out",
                                                      str(folder / "none-out.db"), "--scheduler", a]),
               _one_line(2, "--scheduler"))
    return t.report()


def bad_frames(folder: Path, db: Path) -> dict:
    """Each bad LOW frame through the worker's analysis of a real pair of the demo archive."""
    from controller.calibration.reprocess.plan import load_configs, plan_pairs
    from controller.calibration.reprocess.tasks import analyse_chunk
    from controller.storage.db import open_existing
    from controller.storage.reprocess.archive import read_archive

    with open_existing(db) as store:
        archive = read_archive(store)
    spec, pair = plan_pairs(archive, load_configs(archive), archive.measurements, None)[0]
    analyse_chunk(spec, (pair,))  # the chain is built once, as on a worker
    frames = folder / "frames"
    frames.mkdir()
    good = Path(pair.low).read_bytes()
    cases = {"dev-zero.png": lambda p: p.symlink_to("/dev/zero"),
             "dev-urandom.png": lambda p: p.symlink_to("/dev/urandom"),
             "fifo.png": os.mkfifo, "folder.png": lambda p: p.mkdir(),
             "sparse-1GiB.png": lambda p: os.truncate(_touch(p), 1 << 30),
             "truncated.png": lambda p: p.write_bytes(good[:len(good) // 3]),
             "garbled.png": lambda p: p.write_bytes(good[:64] + os.urandom(len(good) - 64)),
             "empty.png": lambda p: p.write_bytes(b""),
             "proc-environ.png": lambda p: p.symlink_to("/proc/self/environ"),
             "dangling.png": lambda p: p.symlink_to(folder / "nothing-here")}
    t = Tally()
    for name, make in cases.items():
        p = frames / name
        make(p)
        for sha in (pair.low_sha256, ""):  # as recorded, and an archive without hashes
            bad = _with_low(pair, str(p), sha)
            t.case(f"{name} sha={bool(sha)}", lambda b=bad: analyse_chunk(spec, (b,))[0],
                   lambda o, p=p: _counted(o, p, ("unreadable", "missing")))
    for name, (w, h) in {"other-size.png": (64, 48), "huge-claim.png": (8000, 8000)}.items():
        import cv2
        import numpy as np
        p = frames / name
        cv2.imwrite(str(p), np.zeros((h, w), np.uint8))
        bad = _with_low(pair, str(p), "")
        t.case(name, lambda b=bad: analyse_chunk(spec, (b,))[0],
               lambda o, p=p: _counted(o, p, ("unreadable",)))
    return t.report()


def _counted(o, p: Path, statuses: tuple[str, ...]) -> bool:
    """The pair is counted as one of ``statuses`` with a reason naming the frame file."""
    return getattr(o, "status", None) in statuses and str(p) in o.detail


def _with_low(pair, low: str, sha: str):
    import dataclasses

    return dataclasses.replace(pair, low=low, low_sha256=sha)


def _special(p: Path, device: str | None) -> Path:
    """``p`` made a symbolic link to ``device``, or a FIFO."""
    if device:
        p.symlink_to(device)
    else:
        os.mkfifo(p)
    return p


def _touch(p: Path) -> Path:
    p.write_bytes(b"")
    return p


def _source(db: Path, folder: Path, name: str, edit_config=None, sql: str | None = None) -> Path:
    """A copy of ``db`` naming a copy of its configuration, edited."""
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as c:
        config = Path(c.execute("SELECT config_path FROM campaigns").fetchone()[0])
    out = folder / name
    out.mkdir()
    copy = out / "source.db"
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as c, sqlite3.connect(copy) as d:
        c.backup(d)
    data = yaml.safe_load(config.read_text())
    new = out / "plant.yaml"
    if edit_config is not None:
        new = edit_config(data, out) or new
    if new == out / "plant.yaml":
        new.write_text(yaml.safe_dump(data, sort_keys=False))
    with sqlite3.connect(copy) as d:
        d.execute("UPDATE campaigns SET config_path=?", (str(new),))
        if sql:
            d.execute(sql)
    return copy


def _drop_heliostat(data, out):
    data["heliostats"] = [h for h in data["heliostats"] if h["id"] != "H01"]


def _drop_targets(data, out):
    data["targets"] = [t for t in data.get("targets", []) if t["id"] == data["calibration"]["target"]]
    data["calibration"]["target"] = "nowhere"


RECORDS = {
    "heliostat gone": (_drop_heliostat, None),
    "target gone": (_drop_targets, None),
    "heliostat renamed in the rows": (None, "UPDATE heliostat_runs SET heliostat_id='X99' WHERE id=1"),
    "aim not finite": (None, "UPDATE measurements SET aim_e=9e999 WHERE id=1"),
    "campaign row gone": (None, "DELETE FROM campaigns WHERE id=(SELECT MAX(id) FROM campaigns)"),
    "configuration gone": (lambda d, out: out / "missing.yaml", None),
    "configuration is /dev/zero": (lambda d, out: _special(out / "zero.yaml", "/dev/zero"), None),
    "configuration is a FIFO": (lambda d, out: _special(out / "fifo.yaml", None), None),
}


def bad_records(folder: Path, db: Path) -> dict:
    t = Tally()
    for name, (edit, sql) in RECORDS.items():
        try:
            source = _source(db, folder, name.replace(" ", "-").replace("/", ""), edit, sql)
        except sqlite3.Error as exc:  # the schema refuses the edit itself: nothing to reprocess
            t.failures.append(f"{name}: not applied ({exc})")
            continue
        out = source.with_name("out.db")
        t.case(name, lambda s=source, o=out: _cli(["reprocess", "--db", str(s), "--out", str(o),
                                                   "--workers", "1"]),
               lambda o, out=out: _one_line(2)(o) and not out.exists())
    return t.report()


def as_processes(folder: Path, db: Path) -> dict:
    """Real processes: a silent peer, an echo, and the demo archive with every frame special."""
    images = folder / "special-images"
    shutil.copytree(db.parent / "images", images)
    for i, p in enumerate(sorted(images.rglob("*.png"))):
        p.unlink()
        if i % 3 == 0:
            p.symlink_to("/dev/zero")
        elif i % 3 == 1:
            os.mkfifo(p)
        else:
            os.truncate(_touch(p), 1 << 30)
    out = {}
    for name, peer in [("silent", SILENT["silent"]), ("echo", NOT_SCHEDULERS["echo"])]:
        with peer() as port:
            out[f"peer {name}"] = _process(["--db", str(db), "--out", str(folder / f"{name}.db"),
                                            "--scheduler", f"tcp://127.0.0.1:{port}",
                                            "--connect-timeout", str(CONNECT_S)])
    out["every frame special (1 local worker)"] = _process(
        ["--db", str(db), "--out", str(folder / "special.db"), "--images", str(images), "--workers", "1"])
    return out


def _process(args: list[str]) -> dict:
    """``heliocal reprocess args`` as a process: exit status, wall time, lines on stderr (its
    workers' included), its own peak RSS (``VmHWM``: this mm only; ``ru_maxrss`` would start
    from this bench's RSS, inherited at the fork) and the largest of its worker processes
    (``ru_maxrss`` of its children: an upper bound, it includes the command's RSS when each
    was spawned)."""
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", _MEASURED, *args], capture_output=True, text=True)
    figures = json.loads(r.stdout.strip().splitlines()[-1])
    return {**figures, "ms": round((time.perf_counter() - t0) * 1e3),
            "stderr_lines": len(r.stderr.strip().splitlines())}


_MEASURED = """
import contextlib, io, json, resource, sys
from controller.cli import main
with contextlib.redirect_stdout(io.StringIO()):
    code = main(["reprocess", *sys.argv[1:]])
hwm = next(int(ln.split()[1]) for ln in open("/proc/self/status") if ln.startswith("VmHWM:"))
workers = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
print(json.dumps({"exit": code, "peak_rss_mb": round(hwm / 1024, 1),
                  "workers_peak_rss_mb_at_most": round(workers / 1024, 1) if workers else None}))
"""


def categories(folder: Path) -> dict[str, dict]:
    import distributed.security  # noqa: F401 - imported once before the cases are timed

    _cli(["reprocess", "--db", "-", "--out", "-", "--scheduler", "x"])  # the parser built once, likewise
    db = demo(folder / "reprocess-demo", small=True)
    others = {**addressed(NOT_SCHEDULERS), "refused port": _refused_port, "unknown host": _unknown_host}
    silent = addressed(SILENT)
    return {
        "reprocess_not_a_scheduler": _scheduler_cases(folder, others, 5.0, None),
        "reprocess_silent_peers": _scheduler_cases(folder, silent, CONNECT_S, CONNECT_S + MARGIN_S),
        "reprocess_malformed_addresses": malformed(folder),
        "reprocess_bad_frames": bad_frames(folder, db),
        "reprocess_bad_records": bad_records(folder, db),
        "reprocess_as_processes": as_processes(folder, db),
    }
