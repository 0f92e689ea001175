"""A noisy serial line: a pty proxy between a drive and the simulated firmware that damages
the bytes in both directions (fault injection for the link tests and the fault-line benchmark)."""

from __future__ import annotations

import errno
import heapq
import itertools
import os
import pty
import random
import select
import threading
import time
import tty
from collections import Counter


class NoisyLine:
    """A pty proxy that damages the bytes between a drive and the firmware.

    The drive opens ``device``; the proxy opens the firmware's slave device. Every chunk
    read in either direction may lose bytes (``drop``), get a flipped bit (``flip``), get
    bytes doubled (``dup``), all per byte, or be held back (``delay`` per chunk, up to
    ``max_delay_s``, order preserved as on a real line). ``cut(seconds)`` or a random cut
    (``cut_p`` per chunk, ``cut_s`` long) drops everything in both directions meanwhile.
    ``counts`` records what was done.
    """

    def __init__(self, firmware_device: str, seed: int, *, flip=0.0, drop=0.0, dup=0.0, delay=0.0,
                 max_delay_s=0.02, cut_p=0.0, cut_s=0.2) -> None:
        self.rng = random.Random(seed)
        self.p = dict(flip=flip, drop=drop, dup=dup, delay=delay, cut_p=cut_p)
        self.max_delay_s, self.cut_s = max_delay_s, cut_s
        self.counts: Counter[str] = Counter()
        master, slave = pty.openpty()
        tty.setraw(master)
        self.device = os.ttyname(slave)
        os.close(slave)
        self._drive_side = master
        self._fw_side = os.open(firmware_device, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self._fw_side)
        self._cut_until = 0.0
        self._queue: list = []  # (release time, order, fd, bytes)
        self._order = itertools.count()
        self._release = {master: 0.0, self._fw_side: 0.0}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def cut(self, seconds: float = float("inf")) -> None:
        """Drop everything for ``seconds`` (default: until :meth:`restore`)."""
        self._cut_until = time.monotonic() + seconds
        self.counts["cuts"] += 1

    def restore(self) -> None:
        """End a cut now."""
        self._cut_until = 0.0

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        os.close(self._drive_side)
        os.close(self._fw_side)

    def _mangle(self, data: bytes) -> bytes:
        now = time.monotonic()
        if self.p["cut_p"] and self.rng.random() < self.p["cut_p"]:
            self.cut(self.cut_s)
        if now < self._cut_until:
            self.counts["cut_bytes"] += len(data)
            return b""
        out = bytearray()
        for b in data:
            r = self.rng.random()
            if r < self.p["drop"]:
                self.counts["dropped"] += 1
                continue
            if r < self.p["drop"] + self.p["flip"]:
                b ^= 1 << self.rng.randrange(8)
                self.counts["flipped"] += 1
            out.append(b)
            if self.rng.random() < self.p["dup"]:
                out.append(b)
                self.counts["duplicated"] += 1
        return bytes(out)

    def _forward(self, src: int, dst: int) -> None:
        try:
            data = os.read(src, 4096)
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise
            time.sleep(0.005)  # no one has the drive side open yet
            return
        data = self._mangle(data)
        if not data:
            return
        now = time.monotonic()
        release = now
        if self.rng.random() < self.p["delay"]:
            release += self.rng.uniform(0, self.max_delay_s)
            self.counts["delayed"] += 1
        release = max(release, self._release[dst])
        self._release[dst] = release
        heapq.heappush(self._queue, (release, next(self._order), dst, data))

    def _run(self) -> None:
        pair = {self._drive_side: self._fw_side, self._fw_side: self._drive_side}
        while not self._stop.is_set():
            now = time.monotonic()
            while self._queue and self._queue[0][0] <= now:
                _, _, dst, data = heapq.heappop(self._queue)
                try:
                    os.write(dst, data)
                except OSError:
                    self.counts["write_failed"] += 1
            wait = min(0.02, max(0.0, self._queue[0][0] - now)) if self._queue else 0.02
            ready, _, _ = select.select(list(pair), [], [], wait)
            for fd in ready:
                self._forward(fd, pair[fd])
