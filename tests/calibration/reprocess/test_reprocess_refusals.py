"""``heliocal reprocess`` against a bad cluster or a bad archive: one line naming the address,
the file or the record, the documented exit code, in bounded time, nothing else on stderr (no
traceback, no Dask log line, from this process or its workers) and no output left behind.

The peers are real servers on 127.0.0.1 started and stopped by each test (an echo, random
bytes, an HTTP server, one that closes at once, one that accepts and never answers); the Dask
side is a real ``dask scheduler`` with a ``dask worker`` or the command's local cluster; the
frames are real special files (a symbolic link to /dev/zero, a FIFO, a folder, a sparse
oversized file).
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import sqlite3
import subprocess
import time
from pathlib import Path

import pytest
import yaml

from tests.calibration.reprocess.conftest import heliocal
from tests.calibration.reprocess.peers import NOT_SCHEDULERS, SILENT, tcp_peer
from tests.calibration.reprocess.test_reprocess import DASK, dask_cluster
from tests.conftest import run_cli, scaled_s

pytestmark = pytest.mark.xdist_group("reprocess")

CONNECT_S = 1.5  # --connect-timeout of these tests, before the time factor
STARTUP_S = 6.0  # the command's own start and exit around the connect timeout, before the factor


# A sample of each kind of peers.py (benchmarks/adversarial/reprocess.py tries them all).
PEERS = {k: NOT_SCHEDULERS[k] for k in ("echo", "random bytes", "closes at once", "http 400", "claims 1 TiB")}
PEERS.update({k: SILENT[k] for k in ("silent", "http (waits for a request line)")})


def _refused(r: subprocess.CompletedProcess, code: int, *words: str) -> None:
    lines = r.stderr.strip().splitlines()
    assert r.returncode == code and len(lines) == 1, r.stderr
    assert lines[0].startswith("heliocal reprocess: error: ") and all(w in lines[0] for w in words), lines


@pytest.mark.parametrize("kind", list(PEERS))
def test_a_peer_that_is_not_a_dask_scheduler_is_refused_within_the_connect_timeout(kind, tmp_path):
    source = tmp_path / "source.db"
    source.write_bytes(b"")  # the scheduler is checked before the source is opened
    with PEERS[kind]() as port:
        address = f"tcp://127.0.0.1:{port}"
        t0 = time.monotonic()
        r = heliocal("reprocess", "--db", str(source), "--out", str(tmp_path / "new.db"), "--scheduler",
                     address, "--connect-timeout", str(scaled_s(CONNECT_S)), check=False)
        took = time.monotonic() - t0
    _refused(r, 1, address, "Dask scheduler")
    assert took < scaled_s(CONNECT_S + STARTUP_S), took
    if kind in SILENT:
        assert "within the connect timeout" in r.stderr and took >= scaled_s(CONNECT_S)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["source.db"]


def test_a_refused_port_fails_at_once(tmp_path):
    with socket.create_server(("127.0.0.1", 0)) as s:
        port = s.getsockname()[1]  # bound, closed below: nothing listens there
    source = tmp_path / "source.db"
    source.write_bytes(b"")
    t0 = time.monotonic()
    code, _, err = run_cli(["reprocess", "--db", str(source), "--out", str(tmp_path / "new.db"),
                            "--scheduler", f"tcp://127.0.0.1:{port}", "--connect-timeout", "60"])
    assert code == 1 and "cannot connect" in err and len(err.strip().splitlines()) == 1, err
    assert time.monotonic() - t0 < scaled_s(5)


@pytest.mark.parametrize("address, words", [
    ("tcp://" + "a" * 300 + ":8786", "host name of 300 characters"),
    ("tcp://" + ".".join(["b" * 64] * 2) + ":8786", "is not a host name"),
    ("tcp://sched uler:8786", "is not a host name"),
    ("tcp://127.0.0.1:0", "port 0 is outside"),
    ("tcp://127.0.0.1:65536", "port 65536 is outside"),
    ("tcp://[1::2::3]:8786", "is not an IPv6 address"),
    ("tcp://\u0660.example:8786", "is not a host name"),
    ("tls://127.0.0.1:8786", "tls:// needs Dask's TLS settings"),
    ("tcp://127.0.0.1:8786\n", "expected tcp://HOST:PORT"),
])
def test_a_malformed_address_is_bad_input_at_once(address, words, tmp_path):
    t0 = time.monotonic()
    code, out, err = run_cli(["reprocess", "--db", str(tmp_path / "source.db"), "--out",
                              str(tmp_path / "new.db"), "--scheduler", address])
    assert code == 2 and len(err.strip().splitlines()) == 1 and words in err and "\n" not in err.strip(), err
    assert time.monotonic() - t0 < scaled_s(2) and not any(tmp_path.iterdir())


def _moved_archive(field, where: Path) -> tuple[Path, dict[str, Path]]:
    """A copy of the demo's frames for ``--images``, five LOW frames replaced by bad files."""
    images = where / "moved"
    shutil.copytree(field["db"].parent / "images", images)
    frames = sorted(images.rglob("*-low.png"))[:5]
    bad = dict(zip(["device", "fifo", "folder", "oversized", "garbled"], frames, strict=True))
    for p in frames:
        p.unlink()
    bad["device"].symlink_to("/dev/zero")
    os.mkfifo(bad["fifo"])
    bad["folder"].mkdir()
    with open(bad["oversized"], "wb") as f:
        f.truncate(300 << 20)  # sparse: 300 MiB claimed, nothing stored
    bad["garbled"].write_bytes(b"\x89PNG\r\n\x1a\n" + os.urandom(5000))
    return images, bad


def test_bad_frames_are_counted_unreadable_without_reading_them(field, tmp_path):
    images, bad = _moved_archive(field, tmp_path)
    t0 = time.monotonic()
    r = heliocal("reprocess", "--db", str(field["db"]), "--out", str(tmp_path / "new.db"), "--images",
                 str(images), "--workers", "1", "--json")
    assert r.stderr == "" and time.monotonic() - t0 < scaled_s(60)
    f = json.loads(r.stdout)
    assert f["unreadable"] == 5 and f["missing"] == 0 and f["measurements"] + f["no_beam"] == f["pairs"] - 5
    pairs = (Path(f["report"]) / "pairs.csv").read_text()
    for what, words in [("device", "is a character device"), ("fifo", "is a FIFO"),
                        ("folder", "is a directory"), ("oversized", "is too large for a frame"),
                        ("garbled", "SHA-256")]:
        line = next(ln for ln in pairs.splitlines() if bad[what].name in ln)
        assert words in line, line


def _source_with(field, where: Path, edit) -> Path:
    """A copy of the demo database naming a copy of its configuration changed by ``edit(data)``."""
    data = yaml.safe_load(field["config"].read_text())
    edit(data)
    config = where / "edited.yaml"
    config.write_text(yaml.safe_dump(data, sort_keys=False))
    db = where / "source.db"
    with sqlite3.connect(f"file:{field['db']}?mode=ro", uri=True) as c, sqlite3.connect(db) as d:
        c.backup(d)
    with sqlite3.connect(db) as d:
        d.execute("UPDATE campaigns SET config_path=?", (str(config),))
    return db


def _measured(field) -> str:
    with sqlite3.connect(f"file:{field['db']}?mode=ro", uri=True) as c:
        return c.execute("SELECT heliostat_id FROM heliostat_runs ORDER BY id").fetchone()[0]


def test_a_record_the_configuration_no_longer_fits_is_refused_before_any_output(field, tmp_path):
    gone = _measured(field)
    db = _source_with(field, tmp_path, lambda d: d.update(
        heliostats=[h for h in d["heliostats"] if h["id"] != gone]))
    r = heliocal("reprocess", "--db", str(db), "--out", str(tmp_path / "new.db"), "--workers", "1",
                 check=False)
    _refused(r, 2, f"heliostat {gone!r}", "is not in the configuration any more")
    assert not (tmp_path / "new.db").exists()


def test_a_task_refused_on_a_worker_is_one_line_locally_and_on_a_cluster(field, tmp_path):
    """A recognition library the configuration names but a worker cannot read: the worker's
    InputError comes back as the command's one line, with no traceback from the worker."""
    library = tmp_path / "library.yaml"
    library.write_text("entries: [not closed\n")
    db = _source_with(field, tmp_path, lambda d: d.setdefault("calibration", {}).update(library=str(library)))
    local = heliocal("reprocess", "--db", str(db), "--out", str(tmp_path / "local.db"), "--workers", "1",
                     check=False)
    _refused(local, 2, str(library))
    with dask_cluster(tmp_path / "cluster", workers=1) as (address, client):
        remote = heliocal("reprocess", "--db", str(db), "--out", str(tmp_path / "remote.db"),
                          "--scheduler", address, check=False)
        # the worker did not log the task's failure either
        assert "Traceback" not in (tmp_path / "cluster" / "worker0.log").read_text()
        worker = next(iter(client.scheduler_info()["workers"]))
        at_worker = heliocal("reprocess", "--db", str(db), "--out", str(tmp_path / "w.db"), "--scheduler",
                             worker, "--connect-timeout", str(scaled_s(CONNECT_S)), check=False)
    _refused(remote, 2, str(library))
    assert remote.stderr == local.stderr
    _refused(at_worker, 1, worker, "not a Dask scheduler", "a worker")
    assert not (tmp_path / "w.db").exists()


@pytest.fixture
def tls_files(tmp_path) -> dict[str, str]:
    """A self-signed certificate and its key (the certificate is its own CA), by openssl."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed (it makes the test's certificate)")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key), "-out",
                    str(cert), "-days", "1", "-subj", "/CN=127.0.0.1"], check=True, capture_output=True)
    return {"cert": str(cert), "key": str(key)}


def _tls_echo(files: dict[str, str]):
    """An echo behind TLS with the test's certificate: a TLS peer that is no Dask scheduler."""
    import ssl

    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.load_cert_chain(files["cert"], files["key"])

    def handle(conn, stop) -> None:
        with context.wrap_socket(conn, server_side=True) as tls:
            while data := tls.recv(65536):
                tls.sendall(data)
    return tcp_peer(handle)


def test_over_tls_a_real_scheduler_passes_the_check_and_other_peers_do_not(tls_files, tmp_path):
    import dask

    from controller.calibration.reprocess.scheduler import ClusterError, check_scheduler

    file = tmp_path / "scheduler.json"
    tls = ["--tls-ca-file", tls_files["cert"], "--tls-cert", tls_files["cert"], "--tls-key", tls_files["key"]]
    p = subprocess.Popen([str(DASK), "scheduler", "--protocol", "tls", "--host", "127.0.0.1", "--port", "0",
                          "--no-dashboard", "--scheduler-file", str(file), *tls],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    settings = {"distributed.comm.tls.ca-file": tls_files["cert"],
                "distributed.comm.tls.client.cert": tls_files["cert"],
                "distributed.comm.tls.client.key": tls_files["key"]}
    try:
        deadline = time.monotonic() + scaled_s(60)
        while not file.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(file.read_text())["address"]
        assert address.startswith("tls://127.0.0.1:")
        with dask.config.set(settings):
            assert check_scheduler(address, scaled_s(10))["type"] == "Scheduler"
            with _tls_echo(tls_files) as port, pytest.raises(ClusterError, match="echoed the request back"):
                check_scheduler(f"tls://127.0.0.1:{port}", scaled_s(CONNECT_S))
            with NOT_SCHEDULERS["echo"]() as port, pytest.raises(ClusterError, match="TLS handshake failed"):
                check_scheduler(f"tls://127.0.0.1:{port}", scaled_s(CONNECT_S))
    finally:
        p.terminate()
        p.wait(timeout=scaled_s(20))
