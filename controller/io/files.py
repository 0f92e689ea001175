"""Reading a file named by the user: a regular file only, its size checked before reading.

Every bounded reader (:mod:`controller.io.yaml_files`, :mod:`controller.io.json_files`,
:mod:`controller.io.images`, the CSV readers) takes its bytes from :func:`read_bytes`, so a
FIFO (which would block forever), a device (``/dev/zero`` never ends), a directory or an
oversized file is refused at once with one line naming it.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from controller.errors import InputError

_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))
_CHUNK = 1 << 20


def special_kind(mode: int) -> str | None:
    """What a non-regular file is ("a FIFO", "a directory", ...); None for a regular file."""
    if stat.S_ISREG(mode):
        return None
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def check_regular(path: str | Path, what: str = "file") -> None:
    """Refuse ``path`` unless it is missing or a regular file (symbolic links followed): for
    files a library (sqlite, OpenCV) opens itself."""
    p = Path(path)
    try:
        kind = special_kind(os.stat(p).st_mode)
    except FileNotFoundError:
        return
    except OSError as exc:
        raise InputError(f"{p}: cannot read {what}: {exc.strerror or exc}") from None
    if kind is not None:
        raise InputError(f"{p}: is {kind}, not a regular file ({_a(what)} must be one)")


def read_bytes(path: str | Path, what: str = "file", max_bytes: int = 8 << 20) -> bytes:
    """The bytes of the regular file ``path``, at most ``max_bytes``; InputError naming the file
    when it is missing, unreadable, special or too large. The size is checked before reading
    and again while reading (a file growing meanwhile), so nothing larger is ever allocated."""
    p = Path(path)
    check_regular(p, what)
    try:
        # O_NONBLOCK: a FIFO swapped in after the check must not block the open.
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        raise InputError(f"{p}: cannot read {what}: {exc.strerror or exc}") from None
    try:
        st = os.fstat(fd)
        kind = special_kind(st.st_mode)
        if kind is not None:
            raise InputError(f"{p}: is {kind}, not a regular file ({_a(what)} must be one)")
        if st.st_size > max_bytes:
            raise InputError(f"{p}: {st.st_size} bytes is too large for {_a(what)} (at most {max_bytes})")
        chunks, total = [], 0
        while chunk := os.read(fd, min(_CHUNK, max_bytes + 1 - total)):
            chunks.append(chunk)
            total += len(chunk)
            if total > max_bytes:
                raise InputError(f"{p}: grew beyond {max_bytes} bytes while being read ({_a(what)})")
        return b"".join(chunks)
    except OSError as exc:
        raise InputError(f"{p}: cannot read {what}: {exc.strerror or exc}") from None
    finally:
        os.close(fd)


def _a(what: str) -> str:
    return f"{'an' if what[:1] in 'aeiou' else 'a'} {what}"
