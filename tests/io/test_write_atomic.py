"""``write_atomic``, ``write_bytes_atomic``: a file appears whole or not at all, with the mode a
plain open() gives it."""

from __future__ import annotations

import os
import stat
import threading

import pytest

from controller.io.images import write_atomic, write_bytes_atomic


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


WRITERS = {"write_atomic": lambda p, data: write_atomic(p, lambda t: t.write_bytes(data)),
           "write_bytes_atomic": write_bytes_atomic}


@pytest.mark.parametrize("writer", sorted(WRITERS))
def test_files_written_from_many_threads_get_the_umasks_mode(tmp_path, writer):
    """Each of 8 threads writes 25 files at once; every file has mode 0666 less the umask (the
    umask is read once: setting it to read it, per file, would let another thread's file slip
    through with 0666) and its own content."""
    def work(t: int) -> None:
        for i in range(25):
            WRITERS[writer](tmp_path / f"{t}-{i}.bin", f"{t}-{i}".encode())

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


def test_bytes_written_atomically_make_the_missing_folder_and_replace_an_old_file(tmp_path):
    p = tmp_path / "night" / "pass" / "F00001-it0-low.png"
    write_bytes_atomic(p, b"first")
    write_bytes_atomic(p, b"second")
    assert p.read_bytes() == b"second"
    assert [f.name for f in p.parent.iterdir()] == [p.name]  # no temporary file left over


def test_bytes_that_cannot_be_renamed_into_place_leave_nothing(tmp_path):
    (tmp_path / "x.png").mkdir()  # a folder where the file should go: the rename fails
    with pytest.raises(OSError):
        write_bytes_atomic(tmp_path / "x.png", b"data")
    assert [f.name for f in tmp_path.iterdir()] == ["x.png"]
