"""``heliocal reprocess`` against a real Dask scheduler and workers on 127.0.0.1.

The source is the demo database of ``conftest.py``. The checks that do not share the code under
test: the recorded centroids and models (made live by the campaign), a real ``dask scheduler``
and ``dask worker`` processes of the project's environment, SHA-256 of the source before and
after, and a worker process killed with SIGKILL.
"""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import pytest
import yaml

from controller.storage.reprocess.archive import fingerprint
from simplant.archive import replicate
from tests.calibration.reprocess.conftest import REPO
from tests.calibration.reprocess.conftest import heliocal as _heliocal
from tests.conftest import scaled_s

pytestmark = pytest.mark.xdist_group("reprocess")

DASK = Path(sys.executable).with_name("dask")
# Figures that say how the run went, not what it found.
RUN_KEYS = {"workers", "scheduler", "local", "wall_s", "out", "report", "resumed_pairs"}


def _figures(r: subprocess.CompletedProcess) -> dict:
    return json.loads(r.stdout)


def _found(f: dict) -> dict:
    return {k: v for k, v in f.items() if k not in RUN_KEYS and k != "db"}


# One BLAS thread per worker, as Dask's nanny sets for the workers it starts: a worker without a
# nanny would otherwise sum in another order and differ from a local run in the last bits.
ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


@contextmanager
def dask_cluster(where: Path, workers: int = 2):
    """``dask scheduler`` and ``workers`` × ``dask worker`` (no nanny: the worker is the process)
    on 127.0.0.1, from the project's environment; stopped on exit."""
    from dask.distributed import Client

    where.mkdir(parents=True, exist_ok=True)
    file = where / "scheduler.json"
    env = {**os.environ, **ONE_THREAD}
    procs = [subprocess.Popen([str(DASK), "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(file)], stdout=subprocess.DEVNULL, env=env,
                              stderr=open(where / "scheduler.log", "w"))]  # noqa: SIM115
    try:
        deadline = time.monotonic() + scaled_s(60)
        while not file.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        for k in range(workers):
            procs.append(subprocess.Popen(
                [str(DASK), "worker", address, "--host", "127.0.0.1", "--nworkers", "1", "--nthreads", "1",
                 "--no-nanny", "--no-dashboard"], stdout=subprocess.DEVNULL, env=env,
                stderr=open(where / f"worker{k}.log", "w")))  # noqa: SIM115
        with Client(address, timeout=scaled_s(30), set_as_default=False) as client:
            client.wait_for_workers(workers, timeout=scaled_s(60))
            yield address, client
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                p.terminate()
        for p in procs:
            try:
                p.wait(timeout=scaled_s(20))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def _new_models(out: Path, source: Path) -> list[tuple]:
    with sqlite3.connect(f"file:{source}?mode=ro", uri=True) as c:
        last = c.execute("SELECT MAX(id) FROM model_params").fetchone()[0]
    with sqlite3.connect(f"file:{out}?mode=ro", uri=True) as c:
        return c.execute("SELECT heliostat_id, params_json, sigma_json, residual_mrad, n_measurements FROM "
                         "model_params WHERE id > ? ORDER BY heliostat_id", (last,)).fetchall()


def test_cluster_and_local_runs_agree_and_reproduce_the_records(field, tmp_path):
    src = field["db"]
    before = fingerprint(src), (src.stat().st_size, src.read_bytes())
    local = _figures(_heliocal("reprocess", "--db", str(src), "--out", str(tmp_path / "local.db"),
                               "--workers", "2", "--json"))
    with dask_cluster(tmp_path / "cluster") as (address, _client):
        remote = _figures(_heliocal("reprocess", "--db", str(src), "--out", str(tmp_path / "remote.db"),
                                    "--scheduler", address, "--json"))
    assert remote["scheduler"] == address and remote["workers"] == 2 and remote["local"] is False
    assert local["local"] is True and local["workers"] == 2
    assert _found(local) == _found(remote)
    # every pair re-analysed, every model refitted
    with sqlite3.connect(f"file:{src}?mode=ro", uri=True) as c:
        n_pairs = c.execute("SELECT COUNT(DISTINCT measurement_id) FROM images").fetchone()[0]
        heliostats = c.execute("SELECT COUNT(DISTINCT heliostat_id) FROM heliostat_runs").fetchone()[0]
    assert local["pairs"] == local["measurements"] == n_pairs > 10
    assert local["heliostats"] == local["models_refit"] == heliostats == 3
    models = _new_models(tmp_path / "local.db", src)
    assert len(models) == 3 and models == _new_models(tmp_path / "remote.db", src)
    # Same chain, same configuration: the campaign's own centroids and models come back exactly.
    assert local["centroid_shift_mm"]["max"] == 0.0 and local["changed"] == []
    assert local["missing"] == local["unreadable"] == local["no_beam"] == 0 and local["config_changed"] == []
    # the source is byte-identical (database and its write-ahead log)
    assert (fingerprint(src), (src.stat().st_size, src.read_bytes())) == before
    report = Path(local["report"])
    assert {p.name for p in report.iterdir()} >= {"reprocess.md", "heliostats.csv", "models.csv", "pairs.csv",
                                                  "reprocess.png"}
    # a rerun on the finished output does nothing and prints the same figures
    again = _figures(_heliocal("reprocess", "--db", str(src), "--out", str(tmp_path / "local.db"), "--json"))
    assert _found(again) == _found(local) and again["workers"] == 0
    assert len(_new_models(tmp_path / "local.db", src)) == 3


@pytest.fixture(scope="module")
def archive(field, tmp_path_factory) -> Path:
    """The demo's records over 25 nights (about 400 pairs, a dozen tasks): long enough to act mid-run."""
    d = tmp_path_factory.mktemp("archive")
    assert replicate(field["db"], d / "archive.db", d / "images", 25) >= 300
    return d / "archive.db"


@pytest.fixture(scope="module")
def reference(archive, tmp_path_factory) -> tuple[dict, list[tuple]]:
    """An undisturbed local run on ``archive``: its figures and new models."""
    out = tmp_path_factory.mktemp("reference") / "reference.db"
    figures = _figures(_heliocal("reprocess", "--db", str(archive), "--out", str(out), "--workers", "2",
                                 "--json"))
    return figures, _new_models(out, archive)


def _pairs_done(out: Path) -> int:
    if not out.is_file():
        return 0
    try:
        with sqlite3.connect(f"file:{out}?mode=ro", uri=True, timeout=1) as c:
            return c.execute("SELECT COUNT(*) FROM reprocess_pairs").fetchone()[0]
    except sqlite3.OperationalError:
        return 0  # not created yet


def test_a_worker_killed_mid_run_loses_nothing(archive, reference, tmp_path):
    with dask_cluster(tmp_path / "cluster") as (address, client):
        out = tmp_path / "killed.db"
        p = subprocess.Popen([sys.executable, "-m", "controller.cli", "reprocess", "--db", str(archive),
                              "--out", str(out), "--scheduler", address, "--json"], cwd=REPO,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        pids = client.run(os.getpid)
        killed = None
        deadline = time.monotonic() + scaled_s(300)
        while killed is None and p.poll() is None and time.monotonic() < deadline:
            if _pairs_done(out) > 0:  # the run is under way: kill a worker that holds a task
                busy = [w for w, keys in client.processing().items() if keys]
                if busy:
                    done_then = _pairs_done(out)
                    os.kill(pids[busy[0]], signal.SIGKILL)
                    killed = busy[0]
                    continue
            time.sleep(0.02)
        stdout, stderr = p.communicate(timeout=scaled_s(600))
        assert killed is not None, f"the run ended before a worker could be killed:\n{stderr}"
        assert p.returncode == 0, stderr
        assert 0 < done_then
        remaining = client.scheduler_info()["workers"]
        assert killed not in remaining and len(remaining) == 1
    killed_run = json.loads(stdout)
    total = killed_run["pairs"]
    assert done_then < total, "the worker was killed after the last pair"
    assert killed_run["measurements"] == total and killed_run["models_refit"] == killed_run["heliostats"] == 3
    # the same figures as an undisturbed local run
    assert _found(killed_run) == _found(reference[0])
    assert _new_models(out, archive) == reference[1]


def test_an_interrupted_run_continues_where_it_stopped(archive, reference, tmp_path):
    out = tmp_path / "resumed.db"
    p = subprocess.Popen([sys.executable, "-m", "controller.cli", "reprocess", "--db", str(archive), "--out",
                          str(out), "--workers", "1", "--json"], cwd=REPO, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + scaled_s(300)
    while _pairs_done(out) == 0 and p.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    p.send_signal(signal.SIGTERM)
    _, stderr = p.communicate(timeout=scaled_s(120))
    assert p.returncode == 130, stderr
    done = _pairs_done(out)
    assert done > 0
    # the records of an unfinished output are still the source's
    with sqlite3.connect(f"file:{out}?mode=ro", uri=True) as c:
        assert c.execute("SELECT status FROM reprocess_run").fetchone()[0] == "running"
    resumed = _figures(_heliocal("reprocess", "--db", str(archive), "--out", str(out), "--workers", "2",
                                 "--json"))
    assert resumed["resumed_pairs"] == done and resumed["measurements"] == resumed["pairs"] > done
    assert _found(resumed) == _found(reference[0])
    assert _new_models(out, archive) == reference[1]


def test_missing_unreadable_and_changed_inputs_are_counted_and_reported(field, tmp_path):
    """A moved archive (--images) with one frame gone and one damaged, and a configuration whose
    camera responses were removed since recording: each is counted, named and reported."""
    import shutil

    images = tmp_path / "moved"
    shutil.copytree(field["db"].parent / "images", images)
    frames = sorted(images.rglob("*-low.png"))
    frames[0].unlink()
    frames[1].write_bytes(frames[1].read_bytes()[:100])
    # The same records naming a configuration that lost its camera responses (linear sensors).
    db = tmp_path / "source.db"
    with sqlite3.connect(f"file:{field['db']}?mode=ro", uri=True) as c, sqlite3.connect(db) as d:
        c.backup(d)
    data = yaml.safe_load(field["config"].read_text())
    for cam in [data["camera"]] + [t["camera"] for t in data["targets"] if t.get("camera")]:
        cam.pop("crf_file", None)
    linear = tmp_path / "linear.yaml"
    linear.write_text(yaml.safe_dump(data, sort_keys=False))
    with sqlite3.connect(db) as d:
        d.execute("UPDATE campaigns SET config_path=?", (str(linear),))
    before = fingerprint(db)
    f = _figures(_heliocal("reprocess", "--db", str(db), "--out", str(tmp_path / "new.db"), "--images",
                           str(images), "--workers", "1", "--json"))
    assert fingerprint(db) == before
    assert f["missing"] == 1 and f["unreadable"] == 1 and f["measurements"] == f["pairs"] - 2 - f["no_beam"]
    with sqlite3.connect(db) as d:
        assert len(f["config_changed"]) == d.execute("SELECT COUNT(*) FROM campaigns").fetchone()[0]
    # Another camera response moves the centroids: the diff shows it, per pair and per heliostat.
    assert f["centroid_shift_mm"]["max"] > 0.1
    report = Path(f["report"])
    pairs = (report / "pairs.csv").read_text()
    assert frames[0].name in pairs and "frame not found" in pairs
    assert frames[1].name in pairs and "SHA-256" in pairs
    heliostats = (report / "heliostats.csv").read_text().splitlines()
    assert len(heliostats) == 1 + f["heliostats"]
    md = (report / "reprocess.md").read_text()
    assert "frames missing | 1" in md and "frames unreadable | 1" in md
    # a missing or unreadable pair keeps its recorded values in the new database
    with sqlite3.connect(f"file:{tmp_path / 'new.db'}?mode=ro", uri=True) as c:
        kept = c.execute("SELECT COUNT(*) FROM measurements m JOIN reprocess_pairs p "
                         "ON p.measurement_id=m.id WHERE p.status IN ('missing', 'unreadable') "
                         "AND m.centroid_e = p.old_centroid_e").fetchone()[0]
    assert kept == 2


def test_since_limits_the_pairs_and_still_refits_every_heliostat(field, tmp_path):
    f = _figures(_heliocal("reprocess", "--db", str(field["db"]), "--out", str(tmp_path / "new.db"),
                           "--since", "2100-01-01", "--workers", "1", "--json"))
    assert f["pairs"] == 0 and f["heliostats"] == f["models_refit"] == 3
    assert f["since"].startswith("2100-01-01")


@pytest.mark.parametrize("args, words", [
    (["--scheduler", "localhost:8786"], "expected tcp://HOST:PORT"),
    (["--scheduler", "tcp://127.0.0.1:8786", "--workers", "2"], "exclude each other"),
    (["--workers", "0"], "argument --workers: 0 is outside [1, 256]"),
    (["--since", "yesterday"], "--since 'yesterday'"),
    (["--images", "/nonexistent-folder"], "not a folder"),
])
def test_bad_options_are_refused_in_one_line_before_anything_starts(field, tmp_path, args, words):
    out = tmp_path / "new.db"
    r = _heliocal("reprocess", "--db", str(field["db"]), "--out", str(out), *args, check=False)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and words in r.stderr, r.stderr
    assert not any(tmp_path.iterdir())


def test_the_output_is_never_the_source_nor_another_file(field, tmp_path):
    r = _heliocal("reprocess", "--db", str(field["db"]), "--out", str(field["db"]), check=False)
    assert r.returncode == 2 and "is the source database" in r.stderr
    other = tmp_path / "other.db"
    other.write_bytes(b"")
    with sqlite3.connect(other) as c:
        c.execute("CREATE TABLE t (x)")
    content = other.read_bytes()
    r = _heliocal("reprocess", "--db", str(field["db"]), "--out", str(other), "--workers", "1", check=False)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and str(other) in r.stderr, r.stderr
    assert other.read_bytes() == content
