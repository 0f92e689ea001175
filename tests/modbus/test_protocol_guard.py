"""The simulated drive's Modbus TCP port follows the application protocol and MODBUS.md for
requests the register logic never sees: raw frames over a socket."""

from __future__ import annotations

import socket
import struct

import pytest

from simplant.firmware.modbus import ModbusSimServer
from simplant.firmware.modbus_guard import check_pdu
from tests.conftest import scaled_s


def _ask(sock: socket.socket, pdu: bytes, unit: int = 1, tid: int = 7) -> bytes:
    sock.sendall(struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu)
    head = _recv(sock, 7)
    t, proto, length, u = struct.unpack(">HHHB", head)
    assert (t, proto, u) == (tid, 0, unit)
    return _recv(sock, length - 1)


def _recv(sock: socket.socket, n: int) -> bytes:
    out = b""
    while len(out) < n:
        chunk = sock.recv(n - len(out))
        assert chunk, "connection closed"
        out += chunk
    return out


@pytest.fixture
def port(sim):
    return sim.port


@pytest.mark.parametrize("count", [0, 126, 2000])
@pytest.mark.parametrize("fc", [3, 4])
def test_read_counts_outside_1_to_125_are_exception_3(port, fc, count):
    with socket.create_connection(("127.0.0.1", port), timeout=scaled_s(2)) as s:
        assert _ask(s, struct.pack(">BHH", fc, 0, count)) == bytes([fc | 0x80, 3])
        assert _ask(s, struct.pack(">BHH", fc, 0, 1))[0] == fc  # the connection still serves


@pytest.mark.parametrize("fc", [1, 2, 5, 7, 8, 11, 15, 17, 20, 23, 43, 65, 127])
def test_other_functions_are_exception_1_with_the_function_echoed(port, fc):
    with socket.create_connection(("127.0.0.1", port), timeout=scaled_s(2)) as s:
        assert _ask(s, bytes([fc]) + b"\x00\x00\x00\x01") == bytes([(fc | 0x80) & 0xFF, 1])


def test_write_multiple_with_inconsistent_byte_count_is_exception_3(port, sim):
    with socket.create_connection(("127.0.0.1", port), timeout=scaled_s(2)) as s:
        # quantity 2 but 3 bytes: refused before any register changes
        assert _ask(s, struct.pack(">BHHB", 16, 0, 2, 3) + b"\x00\x00\x01") == bytes([0x90, 3])
    assert sim.writes == []


def test_idle_connections_are_closed(controllers):
    server = ModbusSimServer(controllers, idle_timeout_s=scaled_s(0.3))
    port = server.start_tcp()
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=scaled_s(5)) as s:
            assert s.recv(1) == b""  # closed by the server after the idle time
    finally:
        server.stop()


def test_connections_beyond_the_cap_are_refused(controllers):
    server = ModbusSimServer(controllers, max_connections=2)
    port = server.start_tcp()
    try:
        held = [socket.create_connection(("127.0.0.1", port), timeout=scaled_s(2)) for _ in range(2)]
        for s in held:
            assert _ask(s, struct.pack(">BHH", 4, 0, 1))[0] == 4
        with socket.create_connection(("127.0.0.1", port), timeout=scaled_s(2)) as extra:
            assert extra.recv(1) == b""
        assert server.guard.refused_connections == 1
        for s in held:
            s.close()
    finally:
        server.stop()


def test_check_pdu_by_hand():
    assert check_pdu(bytes([3, 0, 0, 0, 125])) is None and check_pdu(bytes([3, 0, 0, 0, 126])) == 3
    assert check_pdu(bytes([6, 0, 8, 0, 1])) is None and check_pdu(bytes([6, 0, 8])) == 3
    assert check_pdu(bytes([16, 0, 0, 0, 1, 2, 0, 5])) is None
    assert check_pdu(bytes([16, 0, 0, 0, 124, 248]) + bytes(248)) == 3
    assert check_pdu(bytes([0x2B, 0x0E, 1, 0])) == 1
