"""TCP peers on 127.0.0.1 that are not lamp panels, each a real socket server in a thread
(started and stopped by the test or benchmark that uses it): ``with NotAPanel("echo") as
peer: peer.port``.

Kinds: ``echo`` (every byte back), ``garbage`` (bytes that are no Modbus frame), ``http`` (an
HTTP error, then close), ``fc05`` (a well-formed write-coil response, whatever was asked),
``two-bytes`` (a read response of the right function with two data bytes for one bit),
``padding`` (one data byte, its unused bits set), ``trickle`` (one garbage byte at a time,
without end), ``closer`` (accepts and closes at once), ``banner`` (a text line on connect, then
silence)."""

from __future__ import annotations

import socket
import struct
import threading

KINDS = ("echo", "garbage", "http", "fc05", "two-bytes", "padding", "trickle", "closer", "banner")


def _answer(kind: str, request: bytes) -> bytes | None:
    """What ``kind`` sends back for one received chunk (None: close the connection)."""
    if kind == "echo":
        return request
    if kind == "garbage":
        return bytes(range(7, 250, 3)) * 3
    if kind == "http":
        return None
    head = request[:7]
    if len(head) < 7:
        return b""
    tid, _, _, unit = struct.unpack(">HHHB", head)
    fc = request[7] if len(request) > 7 else 1
    if kind == "fc05":
        return struct.pack(">HHHBBHH", tid, 0, 6, unit, 5, 0, 0xFF00)
    if kind == "two-bytes":
        return struct.pack(">HHHBBBBB", tid, 0, 5, unit, fc, 2, 1, 0) if fc in (1, 2) else request
    if kind == "padding":
        return struct.pack(">HHHBBBB", tid, 0, 4, unit, fc, 1, 0xFF) if fc in (1, 2) else request
    return b""


class NotAPanel:
    """One peer of ``kind`` (:data:`KINDS`) listening on 127.0.0.1:``port``."""

    def __init__(self, kind: str) -> None:
        if kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
        self.kind = kind
        self._srv = socket.socket()
        self._srv.bind(("127.0.0.1", 0))
        self._srv.listen()
        self.port = self._srv.getsockname()[1]
        self._stop = threading.Event()
        self._conns: list[socket.socket] = []
        self._threads: list[threading.Thread] = []

    def __enter__(self) -> NotAPanel:
        t = threading.Thread(target=self._accept, daemon=True)
        t.start()
        self._threads.append(t)
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        for s in (self._srv, *self._conns):  # shutdown wakes a thread blocked in accept or recv
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            s.close()
        for t in self._threads:
            t.join(timeout=5)

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._srv.accept()
            except OSError:
                return
            self._conns.append(conn)
            t = threading.Thread(target=self._serve, args=(conn,), daemon=True)
            t.start()
            self._threads.append(t)

    def _serve(self, conn: socket.socket) -> None:
        try:
            if self.kind == "closer":
                return
            if self.kind == "banner":
                conn.sendall(b"SSH-2.0-OpenSSH_9.6\r\n")
            while not self._stop.is_set():
                if self.kind == "trickle":
                    conn.sendall(b"\x5a")
                    self._stop.wait(0.02)
                    continue
                request = conn.recv(4096)
                if not request:
                    return
                if self.kind == "http":
                    conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")
                    return
                reply = _answer(self.kind, request)
                if reply:
                    conn.sendall(reply)
        except OSError:
            return
        finally:
            conn.close()
