"""TCP peers on 127.0.0.1 that are not Dask schedulers, for ``reprocess --scheduler``: the tests
here and ``benchmarks/adversarial/reprocess.py`` start them (a real server each, stopped on exit).

``NOT_SCHEDULERS`` answer at once with something else (or hang up); ``SILENT`` never give a
whole answer, so only ``--connect-timeout`` ends the wait. Each value is a context manager
factory yielding the port.
"""

from __future__ import annotations

import contextlib
import http.server
import os
import socket
import struct
import threading

import msgpack

# What a scheduler says first (distributed's comm handshake), framed as Dask frames a message.
HELLO = {"compression": None, "python": (3, 11, 0), "pickle-protocol": 5}


def dask_message(msg) -> bytes:
    """``msg`` in Dask's TCP framing: block length, frame count, frame lengths, msgpack frame."""
    frame = msgpack.dumps(msg, use_bin_type=True)
    block = struct.pack("<QQ", 1, len(frame)) + frame
    return struct.pack("<Q", len(block)) + block


@contextlib.contextmanager
def tcp_peer(handle, *, accept: bool = True):
    """A TCP server on 127.0.0.1 calling ``handle(conn, stop)`` per connection on its own
    thread (``accept`` False: it listens and never accepts); yields the port; ``stop`` is set
    and every socket closed on exit."""
    server = socket.create_server(("127.0.0.1", 0), backlog=8)
    stop, conns = threading.Event(), []

    def serve() -> None:
        while accept:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            conns.append(conn)
            threading.Thread(target=_quietly, args=(handle, conn, stop), daemon=True).start()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield server.getsockname()[1]
    finally:
        stop.set()
        with contextlib.suppress(OSError):
            server.shutdown(socket.SHUT_RDWR)  # wakes the accept()
        server.close()
        for c in conns:
            c.close()
        thread.join(5)


def _quietly(handle, conn, stop) -> None:
    with contextlib.suppress(OSError):
        handle(conn, stop)


def _echo(conn, stop) -> None:
    while data := conn.recv(65536):
        conn.sendall(data)


def _random_bytes(conn, stop) -> None:
    while not stop.is_set():
        conn.sendall(os.urandom(65536))


def _close_at_once(conn, stop) -> None:
    conn.close()


def _reset(conn, stop) -> None:
    conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    conn.close()


def _banner(conn, stop) -> None:
    conn.sendall(b"SSH-2.0-OpenSSH_9.6\r\n")
    stop.wait()


def _huge_length(conn, stop) -> None:
    conn.sendall(struct.pack("<Q", 1 << 40))
    zeros = bytes(65536)
    while not stop.is_set():
        conn.sendall(zeros)


def _garbled_frames(conn, stop) -> None:
    conn.sendall(struct.pack("<QQ", 4096, 1 << 60) + os.urandom(4088))
    stop.wait()


def _not_msgpack(conn, stop) -> None:
    block = struct.pack("<QQ", 1, 6) + b"\xc1\xc1\xc1\xc1\xc1\xc1"  # 0xc1: never used by msgpack
    conn.sendall(struct.pack("<Q", len(block)) + block)
    stop.wait()


def _another_dask_server(conn, stop) -> None:
    conn.sendall(dask_message(HELLO) + dask_message({"type": "Worker", "id": "tcp://127.0.0.1:1"}))
    stop.wait()


def _list_instead(conn, stop) -> None:
    conn.sendall(dask_message(HELLO) + dask_message([1, 2, 3]))
    stop.wait()


def _silent(conn, stop) -> None:
    stop.wait()


def _hello_then_silent(conn, stop) -> None:
    conn.sendall(dask_message(HELLO))
    stop.wait()


def _trickle(conn, stop) -> None:
    """A byte of a valid handshake every 50 ms: each read gets something, the whole never comes."""
    for b in dask_message(HELLO):
        if stop.wait(0.05):
            return
        conn.sendall(bytes([b]))
    stop.wait()


class _QuietHandler(http.server.BaseHTTPRequestHandler):
    def log_message(self, *args) -> None:  # the caller's stderr is not under test
        pass


@contextlib.contextmanager
def http_peer():
    """Python's HTTP server (it waits for a request line the Dask handshake never ends)."""
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _QuietHandler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield server.server_address[1]
    finally:
        server.shutdown()
        server.server_close()


@contextlib.contextmanager
def http_answering_peer():
    """An HTTP server that answers whatever comes with a 400 status line at once."""
    def answer(conn, stop) -> None:
        conn.recv(4096)
        conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\nConnection: close\r\n\r\n")
        conn.close()
    with tcp_peer(answer) as port:
        yield port


NOT_SCHEDULERS = {
    "echo": lambda: tcp_peer(_echo),
    "random bytes": lambda: tcp_peer(_random_bytes),
    "closes at once": lambda: tcp_peer(_close_at_once),
    "resets": lambda: tcp_peer(_reset),
    "http 400": http_answering_peer,
    "ssh banner": lambda: tcp_peer(_banner),
    "claims 1 TiB": lambda: tcp_peer(_huge_length),
    "garbled frames": lambda: tcp_peer(_garbled_frames),
    "not msgpack": lambda: tcp_peer(_not_msgpack),
    "a Dask worker's identity": lambda: tcp_peer(_another_dask_server),
    "a list, not a dict": lambda: tcp_peer(_list_instead),
}
SILENT = {
    "silent": lambda: tcp_peer(_silent),
    "never accepts": lambda: tcp_peer(_silent, accept=False),
    "handshake, then silent": lambda: tcp_peer(_hello_then_silent),
    "trickles a byte at a time": lambda: tcp_peer(_trickle),
    "http (waits for a request line)": http_peer,
}
