"""``write_atomic``: a file appears whole or not at all, with the mode a plain open() gives it."""

from __future__ import annotations

import os
import stat
import threading

import pytest

from controller.io.images import write_atomic


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_files_written_from_many_threads_get_the_umasks_mode(tmp_path):
    """Each of 8 threads writes 25 files at once; every file has mode 0666 less the umask (the
    umask is read once: setting it to read it, per file, would let another thread's file slip
    through with 0666) and its own content."""
    def work(t: int) -> None:
        for i in range(25):
            write_atomic(tmp_path / f"{t}-{i}.bin", lambda p, t=t, i=i: p.write_bytes(f"{t}-{i}".encode()))

    threads = [threading.Thread(target=work, args=(t,)) for t in range(8)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    files = sorted(tmp_path.iterdir())
    assert len(files) == 200  # no temporary file left over
    want = 0o666 & ~_umask()
    for f in files:
        assert stat.S_IMODE(f.stat().st_mode) == want, f
        assert f.read_bytes() == f.stem.encode()


def test_a_writer_that_fails_leaves_nothing(tmp_path):
    def fail(p):
        p.write_bytes(b"half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        write_atomic(tmp_path / "x.png", fail)
    assert list(tmp_path.iterdir()) == []
