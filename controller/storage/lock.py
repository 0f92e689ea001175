"""One campaign process per database: an exclusive lock beside the database file.

Two processes running campaigns on one database would drive the same heliostats and could put
two beams on one target. The lock is ``<db>.lock``, held with ``flock`` for as long as the
process runs a campaign; it names its owner (pid, host, since when). The kernel drops an
``flock`` when its process dies, even by ``kill -9``, so a lock file left by a dead process is
stale by construction and is simply taken over. (``flock`` is local to one machine: keep the
database on a local disk, not a network share.)

The process that created the lock file removes it on release — a refused run leaves no
``<db>.lock`` — and only that one: a lock file found there is left (emptied). It is removed
while still locked, and a process that locked a file no longer at the path locks again, so two
processes never hold "the" lock at once.
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
from pathlib import Path

from controller.calibration.records import utc_now
from controller.errors import InputError


class DatabaseBusy(InputError):
    """Another live process holds the database's campaign lock (exit status 2)."""


class CampaignLock:
    """The exclusive campaign lock of database ``db``; :meth:`acquire` / :meth:`release`."""

    def __init__(self, db: str | Path) -> None:
        self.db = Path(db)
        self.path = self.db.with_name(self.db.name + ".lock")
        self._fd: int | None = None
        self._created = False

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self, what: str = "campaign") -> None:
        """Take the lock or raise :class:`DatabaseBusy` naming the owner."""
        if self._fd is not None:
            return
        while True:
            try:
                fd, created = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644), True
            except FileExistsError:
                try:
                    fd, created = os.open(self.path, os.O_RDWR), False
                except FileNotFoundError:
                    continue  # its holder removed it in between: create it
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                owner = self.owner() or {}
                os.close(fd)
                raise DatabaseBusy(
                    f"{self.db}: in use by another {owner.get('what', 'campaign')} "
                    f"(pid {owner.get('pid', '?')} on {owner.get('host', '?')} "
                    f"since {owner.get('since', '?')}); wait for it or stop it first") from None
            if _same_file(fd, self.path):
                break
            os.close(fd)  # locked a file its holder removed on release: lock the one at the path now
        self._created = created
        info = json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "since": utc_now(),
                           "what": what}).encode()
        os.ftruncate(fd, 0)
        os.pwrite(fd, info, 0)
        self._fd = fd

    def owner(self) -> dict | None:
        """The recorded owner of the lock file (whether or not it is still held), or None."""
        try:
            return json.loads(self.path.read_text(encoding="utf-8") or "null")
        except (OSError, ValueError):
            return None

    def release(self) -> None:
        """Unlock; a lock file this process created is removed (while still locked, so a process
        waiting on it sees it gone and locks the path afresh), one it found is left empty."""
        if self._fd is not None:
            if self._created:
                self.path.unlink(missing_ok=True)
            else:
                os.ftruncate(self._fd, 0)
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None


def _same_file(fd: int, path: Path) -> bool:
    """Whether the open file ``fd`` is still the one at ``path``."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return False
    here = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (here.st_dev, here.st_ino)
