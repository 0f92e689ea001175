"""The Modbus application-protocol checks of the simulated drive's TCP port, in front of the
pymodbus server (which answers some malformed requests with the wrong exception).

Per request (MBAP header + PDU, Modbus Application Protocol V1.1b3, Sect. 4 and 6):

* a function other than 3, 4, 6, 16 → exception 01 (illegal function), the function code
  echoed with bit 7 set (MODBUS.md, "Exception responses");
* a read (3, 4) of a quantity outside 1..125, a write-multiple (16) of a quantity outside
  1..123 or whose byte count is not 2 × quantity, or a PDU of the wrong length → exception 03;
* everything else goes, unchanged, to the pymodbus server behind it.

The port also closes connections idle for ``idle_timeout_s`` and accepts at most
``max_connections`` at once (a further client is closed at once), so a forgotten or hostile
client cannot hold the simulated drive forever.
"""

from __future__ import annotations

import asyncio
import contextlib
import struct

READ_FC = (3, 4)
MAX_READ = 125  # registers per read (Modbus spec, Sect. 6.3/6.4)
MAX_WRITE = 123  # registers per FC16 (Sect. 6.12)
MAX_PDU = 253
ILLEGAL_FUNCTION = 1
ILLEGAL_VALUE = 3


def check_pdu(pdu: bytes) -> int | None:
    """The exception code a request PDU must get before it reaches the device, or None."""
    fc = pdu[0]
    body = pdu[1:]
    if fc in READ_FC:
        if len(body) != 4:
            return ILLEGAL_VALUE
        _, qty = struct.unpack(">HH", body)
        return None if 1 <= qty <= MAX_READ else ILLEGAL_VALUE
    if fc == 6:
        return None if len(body) == 4 else ILLEGAL_VALUE
    if fc == 16:
        if len(body) < 5:
            return ILLEGAL_VALUE
        _, qty, nbytes = struct.unpack(">HHB", body[:5])
        ok = 1 <= qty <= MAX_WRITE and nbytes == 2 * qty and len(body) == 5 + nbytes
        return None if ok else ILLEGAL_VALUE
    return ILLEGAL_FUNCTION


class ModbusGuard:
    """Listens on ``host:port`` and forwards checked requests to ``backend`` (host, port)."""

    def __init__(self, backend: tuple[str, int], *, idle_timeout_s: float = 60.0, max_connections: int = 16):
        self.backend = backend
        self.idle_timeout_s = idle_timeout_s
        self.max_connections = max_connections
        self.open_connections = 0
        self.refused_connections = 0
        self.exceptions_sent = 0
        self._server: asyncio.base_events.Server | None = None
        self._tasks: set[asyncio.Task] = set()

    async def start(self, host: str, port: int) -> int:
        self._server = await asyncio.start_server(self._client, host, port)
        return self._server.sockets[0].getsockname()[1]

    async def close(self) -> None:
        """Stop listening and drop every open connection."""
        if self._server is not None:
            self._server.close()
            self._server = None
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self.open_connections >= self.max_connections:
            self.refused_connections += 1
            writer.close()
            return
        self.open_connections += 1
        task = asyncio.current_task()
        self._tasks.add(task)
        try:
            up_reader, up_writer = await asyncio.open_connection(*self.backend)
        except OSError:
            self.open_connections -= 1
            self._tasks.discard(task)
            writer.close()
            return
        # Replies and local exceptions go to the client whole, one frame at a time.
        lock = asyncio.Lock()

        async def replies() -> None:
            # The device's answers, unchanged and in its order (requests are pipelined by
            # transaction id, so a silent unit holds up nobody).
            with contextlib.suppress(asyncio.IncompleteReadError, ConnectionError):
                while True:
                    head = await up_reader.readexactly(7)
                    frame = head + await up_reader.readexactly(struct.unpack(">HHHB", head)[2] - 1)
                    async with lock:
                        writer.write(frame)
                        await writer.drain()

        pump = asyncio.create_task(replies())
        try:
            while True:
                header = await asyncio.wait_for(reader.readexactly(7), self.idle_timeout_s)
                tid, proto, length, unit = struct.unpack(">HHHB", header)
                if proto != 0 or not 2 <= length <= MAX_PDU + 1:
                    return  # not Modbus TCP: drop the connection, as a device would
                pdu = await asyncio.wait_for(reader.readexactly(length - 1), self.idle_timeout_s)
                code = check_pdu(pdu)
                if code is None:
                    up_writer.write(header + pdu)
                    await up_writer.drain()
                    continue
                self.exceptions_sent += 1
                async with lock:
                    writer.write(struct.pack(">HHHBBB", tid, 0, 3, unit, (pdu[0] | 0x80) & 0xFF, code))
                    await writer.drain()
        except (TimeoutError, asyncio.IncompleteReadError, ConnectionError):
            return  # idle too long, or the client went away
        finally:
            pump.cancel()
            self._tasks.discard(task)
            self.open_connections -= 1
            up_writer.close()
            writer.close()
