"""Is ``--scheduler ADDRESS`` a Dask scheduler? Checked before any work is sent (docs/reprocess.md).

Dask's own client trusts its peer: it waits for the peer's handshake without a deadline (a
silent peer hangs it forever), allocates whatever length the peer's first 8 bytes announce,
and unpickles what the peer marks as pickled. So the address is first parsed here (a
malformed one is bad input, exit 2, before anything is opened), then probed with one bounded
exchange of Dask's wire protocol under a single deadline (``--connect-timeout``): name lookup,
TCP (and TLS) connect, Dask's handshake, and the ``identity`` request a scheduler answers with
``{"type": "Scheduler", ...}``. Every read is bounded by :data:`MAX_ANSWER_BYTES` and decoded
as plain msgpack (never unpickled). Anything but a scheduler's answer in time is a
:class:`ClusterError` naming the address and what the peer did (exit 1).

The wire format (distributed's TCP comm): each message is an 8-byte little-endian length of a
block, the block holding the frame count, each frame's length (8 bytes each) and the frames;
the first frame is the msgpack of the message.
"""

from __future__ import annotations

import ipaddress
import pickle
import re
import socket
import ssl
import struct
import sys
import threading
import time
from dataclasses import dataclass

from controller.errors import HeliocalError, InputError

# A scheduler's handshake is ~60 bytes and its identity (asked with n_workers=0) ~300 bytes.
MAX_ANSWER_BYTES = 1 << 16
MAX_HOST_CHARS = 253  # a DNS name (RFC 1035), at most 63 per label
SHOWN_CHARS = 80  # of an address or a peer's answer quoted in an error line
SHOWN_BYTES = 32  # of a peer's raw bytes

_ADDRESS = re.compile(r"(tcp|tls)://(\[[0-9A-Fa-f:.]+\]|[^\[\]:/]+):([0-9]{1,5})")
# Underscores too: resolvers accept them (container and /etc/hosts names), DNS does not.
_LABEL = re.compile(r"[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,61}[A-Za-z0-9_])?")


class ClusterError(HeliocalError):
    """The Dask cluster cannot be reached, is not one, or has no worker (exit 1: the plant's
    computers, not the input)."""


@dataclass(frozen=True)
class SchedulerAddress:
    """A parsed ``tcp://HOST:PORT`` or ``tls://HOST:PORT`` (``host`` without IPv6 brackets)."""

    text: str
    scheme: str
    host: str
    port: int


def shown(text: str) -> str:
    """``text`` quoted for an error line, cut to :data:`SHOWN_CHARS`."""
    return repr(text if len(text) <= SHOWN_CHARS else text[:SHOWN_CHARS] + "…")


def parse_scheduler_address(text: str) -> SchedulerAddress:
    """``tcp://HOST:PORT`` or ``tls://HOST:PORT``: HOST an IPv4 address, an IPv6 address in
    brackets or a host name (letters, digits, ``_`` and inner hyphens; labels of 1 … 63, at
    most 253 characters), PORT 1 … 65535. InputError (exit 2) naming the address otherwise."""
    m = _ADDRESS.fullmatch(text)
    if m is None:
        raise InputError(f"--scheduler {shown(text)}: expected tcp://HOST:PORT (or tls://HOST:PORT)")
    scheme, host, port = m.group(1), m.group(2), int(m.group(3))
    if not 1 <= port <= 65535:
        raise InputError(f"--scheduler {shown(text)}: port {port} is outside 1 … 65535")
    if host.startswith("["):
        try:
            host = str(ipaddress.IPv6Address(host[1:-1]))
        except ValueError:
            raise InputError(f"--scheduler {shown(text)}: {shown(host)} is not an IPv6 address") from None
    elif len(host) > MAX_HOST_CHARS:
        raise InputError(f"--scheduler {shown(text)}: host name of {len(host)} characters (at most "
                         f"{MAX_HOST_CHARS})")
    elif not all(_LABEL.fullmatch(label) for label in host.split(".")):
        raise InputError(f"--scheduler {shown(text)}: {shown(host)} is not a host name (letters, digits, "
                         "_ and inner hyphens, dot-separated labels of 1 … 63) nor an IP address")
    return SchedulerAddress(text, scheme, host, port)


def tls_context(address: SchedulerAddress) -> ssl.SSLContext | None:
    """Dask's client TLS context for a ``tls://`` address (``distributed.comm.tls.*`` of the
    Dask configuration), None for ``tcp://``. InputError when a ``tls://`` address finds no
    TLS settings: the connection could never be made."""
    if address.scheme != "tls":
        return None
    from distributed.security import Security

    context = Security().get_connection_args("client").get("ssl_context")
    if context is None:
        raise InputError(f"--scheduler {shown(address.text)}: tls:// needs Dask's TLS settings "
                         "(distributed.comm.tls.ca-file, .client.cert and .client.key in the Dask "
                         "configuration), and none are set")
    return context


def check_scheduler(text: str, timeout_s: float) -> dict:
    """:func:`probe` the scheduler at ``text`` (parsed first: InputError when malformed or a
    ``tls://`` without TLS settings)."""
    address = parse_scheduler_address(text)
    return probe(address, timeout_s, tls_context(address))


def probe(address: SchedulerAddress, timeout_s: float, context: ssl.SSLContext | None = None) -> dict:
    """The identity a Dask scheduler at ``address`` gives (``type``, ``id``, ``n_workers``, ...),
    within ``timeout_s`` all told. ClusterError naming the address and what went wrong: no such
    host, refused, silent, closed, or an answer that is not a Dask scheduler's."""
    session = _Probe(f"--scheduler {shown(address.text)}", time.monotonic() + timeout_s, timeout_s)
    sock = session.connect(address, context)
    try:
        session.send(sock, _message({"compression": None, "python": tuple(sys.version_info)[:3],
                                   "pickle-protocol": pickle.HIGHEST_PROTOCOL})
                   + _message({"op": "identity", "n_workers": 0, "reply": True}))
        hello = session.read_message(sock)
        if not (isinstance(hello, dict) and {"compression", "pickle-protocol"} <= hello.keys()):
            raise session.error(f"its handshake {_shown_value(hello)} is not Dask's")
        answer = session.read_message(sock)
    finally:
        sock.close()
    kind = answer.get("type") if isinstance(answer, dict) else None
    if kind == "Scheduler":
        return answer
    if isinstance(answer, dict) and answer.get("op") == "identity":
        raise session.error("it echoed the request back")
    if isinstance(answer, dict) and answer.get("status") == "uncaught-error":
        raise session.error("a Dask server that refused a scheduler's request: a worker or a nanny?")
    raise session.error(f"it answered {_shown_value(answer)}")


def _message(msg: dict) -> bytes:
    import msgpack

    frame = msgpack.dumps(msg, use_bin_type=True)
    block = struct.pack("<QQ", 1, len(frame)) + frame
    return struct.pack("<Q", len(block)) + block


@dataclass
class _Probe:
    """One exchange with the peer under one deadline; ``where`` names the address in errors."""

    where: str
    deadline: float
    timeout_s: float

    def error(self, why: str) -> ClusterError:
        return ClusterError(f"{self.where}: not a Dask scheduler ({why})")

    def failed(self, what: str) -> ClusterError:
        return ClusterError(f"{self.where}: {what}")

    def late(self, doing: str) -> ClusterError:
        return self.failed(f"did not {doing} within the connect timeout ({self.timeout_s:g} s): not a "
                           "Dask scheduler, or one too busy to answer")

    def left(self, doing: str) -> float:
        left = self.deadline - time.monotonic()
        if left <= 0:
            raise self.late(doing)
        return left

    def resolve(self, address: SchedulerAddress) -> list:
        """getaddrinfo in a daemon thread: a resolver that hangs must hold neither the deadline
        nor the process at exit."""
        found: list = []

        def lookup() -> None:
            try:
                found.append(socket.getaddrinfo(address.host, address.port, type=socket.SOCK_STREAM))
            except (OSError, UnicodeError) as exc:
                found.append(exc)

        t = threading.Thread(target=lookup, name="heliocal-scheduler-lookup", daemon=True)
        t.start()
        t.join(self.left("resolve its host name"))
        if not found:
            raise self.late(f"resolve the host name {shown(address.host)}")
        if isinstance(found[0], Exception):
            reason = getattr(found[0], "strerror", None) or str(found[0])
            raise self.failed(f"no such host {shown(address.host)} ({reason})")
        return found[0]

    def connect(self, address: SchedulerAddress, context: ssl.SSLContext | None) -> socket.socket:
        """A connected (TLS-wrapped with ``context``) socket; a refused connection fails at once."""
        last = "no address"
        for family, kind, proto, _name, sockaddr in self.resolve(address):
            sock = socket.socket(family, kind, proto)
            try:
                sock.settimeout(self.left("accept the connection"))
                sock.connect(sockaddr)
                if context is None:
                    return sock
                sock.settimeout(self.left("complete the TLS handshake"))
                return context.wrap_socket(sock, server_hostname=address.host)
            except TimeoutError:
                sock.close()
                raise self.late("accept the connection" if context is None else
                                "complete the TLS handshake") from None
            except ssl.SSLError as exc:
                sock.close()
                raise self.failed(f"TLS handshake failed ({exc.reason or exc}): not a Dask scheduler "
                                  "with these TLS settings") from None
            except OSError as exc:
                sock.close()
                last = exc.strerror or str(exc)
        raise self.failed(f"cannot connect ({last}): no Dask scheduler there")

    def send(self, sock: socket.socket, data: bytes) -> None:
        try:
            sock.settimeout(self.left("take the request"))
            sock.sendall(data)
        except TimeoutError:
            raise self.late("take the request") from None
        except OSError as exc:
            raise self.failed(f"the connection failed while sending ({exc.strerror or exc}): not a Dask "
                              "scheduler") from None

    def read_message(self, sock: socket.socket):
        """One message of Dask's TCP framing, at most :data:`MAX_ANSWER_BYTES`, as plain msgpack."""
        import msgpack

        head = self.recv(sock, 8)
        (size,) = struct.unpack("<Q", head)
        if not 16 <= size <= MAX_ANSWER_BYTES:
            raise self.error(f"its answer starts {_shown_bytes(head, sock)}, not a Dask message")
        block = self.recv(sock, size)
        (n_frames,) = struct.unpack_from("<Q", block)
        if not 1 <= n_frames <= (size - 8) // 8:
            raise self.error(f"a garbled message of {n_frames} frames")
        lengths = struct.unpack_from(f"<{n_frames}Q", block, 8)
        start = 8 + 8 * n_frames
        if start + lengths[0] > size or sum(lengths) > MAX_ANSWER_BYTES:
            raise self.error("a garbled message: frames beyond its length")
        try:
            return msgpack.loads(block[start:start + lengths[0]], raw=False, strict_map_key=False)
        except Exception:  # noqa: BLE001 - any bytes may come back; msgpack raises many kinds
            raise self.error("its answer is not msgpack") from None

    def recv(self, sock: socket.socket, n: int) -> bytes:
        data = b""
        while len(data) < n:
            try:
                sock.settimeout(self.left("answer"))
                chunk = sock.recv(n - len(data))
            except TimeoutError:
                raise self.late("answer") from None
            except OSError as exc:
                raise self.failed(f"the connection failed ({exc.strerror or exc}): not a Dask "
                                  "scheduler") from None
            if not chunk:
                said = f"after {_shown_bytes(data)}" if data else "without answering"
                raise self.failed(f"closed the connection {said}: not a Dask scheduler")
            data += chunk
        return data


def _shown_bytes(data: bytes, sock: socket.socket | None = None) -> str:
    """The peer's first bytes for an error line, with what else is already waiting (up to
    :data:`SHOWN_BYTES`): an HTTP server's status line, a banner."""
    if sock is not None:
        try:
            sock.setblocking(False)
            data += sock.recv(SHOWN_BYTES)
        except OSError:
            pass
    text = repr(data[:SHOWN_BYTES])
    return text + ("…" if len(data) > SHOWN_BYTES else "")


def _shown_value(value) -> str:
    text = repr(value)
    return text if len(text) <= SHOWN_CHARS else text[:SHOWN_CHARS] + "…"
