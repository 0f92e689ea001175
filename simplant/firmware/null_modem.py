"""A serial null modem made of two pseudo-terminals, for Modbus RTU without hardware."""

from __future__ import annotations

import contextlib
import os
import selectors
import threading
import tty


class NullModem:
    """Two pty pairs bridged by a thread: bytes written on one end come out of the other.

    ``server_path`` and ``client_path`` are the slave device names. The master ends are raw
    and the slaves are set raw at once, so nothing is echoed before pyserial opens them."""

    def __init__(self) -> None:
        self._m1, self._s1 = os.openpty()
        self._m2, self._s2 = os.openpty()
        for fd in (self._m1, self._s1, self._m2, self._s2):
            tty.setraw(fd)
        self.server_path = os.ttyname(self._s1)
        self.client_path = os.ttyname(self._s2)
        self._stop_r, self._stop_w = os.pipe()
        self._thread = threading.Thread(target=self._run, name="modbus-null-modem", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        sel = selectors.DefaultSelector()
        peer = {self._m1: self._m2, self._m2: self._m1}
        for fd in peer:
            sel.register(fd, selectors.EVENT_READ)
        sel.register(self._stop_r, selectors.EVENT_READ)
        while True:
            for key, _ in sel.select():
                if key.fd == self._stop_r:
                    sel.close()
                    return
                try:
                    data = os.read(key.fd, 4096)
                    os.write(peer[key.fd], data)
                except OSError:
                    continue  # the far side is closed for a moment (client reconnecting)

    def close(self) -> None:
        os.write(self._stop_w, b"x")
        self._thread.join(timeout=2)
        for fd in (self._m1, self._s1, self._m2, self._s2, self._stop_r, self._stop_w):
            with contextlib.suppress(OSError):
                os.close(fd)
