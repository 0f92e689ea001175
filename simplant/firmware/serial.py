"""Simulated actuator firmware serving the serial frame protocol on a real pty.

The firmware owns the pty's master side (raw mode) and answers requests for each bus
address it serves from a :class:`simplant.firmware.physics.SimController`. The code under test
opens the slave device (``start()`` returns its path, optionally also reachable through a
symlink) exactly as it would open an RS-485 adapter. Nothing but bytes on the pty is shared
with the controller.

Duplicate handling (PROTOCOL.md, "Retries"): per address, the firmware keeps the last
request (sequence number, command, payload) and the reply it sent. A request equal to it is
answered from that reply without being executed again; anything else is executed.
"""

from __future__ import annotations

import errno
import os
import pty
import select
import struct
import threading
import tty
from collections import Counter
from pathlib import Path

from firmware_proto.codec import Decoder, Frame, encode
from firmware_proto.faults import Reject
from firmware_proto.messages import (
    LIMITS,
    MAX_PING,
    PAIR,
    PROTOCOL_VERSION,
    REPLY_BIT,
    REQUEST_LENGTH,
    Command,
    Info,
    Status,
    ack,
    nak,
)
from simplant.firmware.physics import SimController

_POLL_S = 0.05  # how often the serving loop looks at its stop event
_NO_PEER_S = 0.005  # back-off while no one has the slave side open (reads give EIO)


class SerialSimFirmware:
    """Simulated firmware for the bus addresses in ``controllers``, on a pty it creates.

    ``controllers[address].log`` is the firmware's own log of executed commands;
    ``stats`` counts frames received, duplicates answered from the cache, frames ignored
    and decoder rejections by reason (``"rejected_crc"``, ...).
    """

    def __init__(self, controllers: dict[int, SimController], link_path: str | None = None) -> None:
        if not controllers:
            raise ValueError("the firmware needs at least one bus address")
        bad = [a for a in controllers if not 1 <= a <= 247]
        if bad:
            raise ValueError(f"bus addresses must be 1..247, got {bad}")
        self.controllers = dict(controllers)
        self.link_path = link_path
        self.device: str | None = None
        self.stats: Counter[str] = Counter()
        self.last_error: str | None = None  # the last command the firmware failed to execute
        self._master: int | None = None
        self._cache: dict[int, tuple[tuple[int, int, bytes], bytes]] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- lifecycle ---------------------------------------------------------------------------
    def open(self) -> str:
        """Create the pty (and the symlink); return the slave device path."""
        if self._master is not None:
            return self.device
        master, slave = pty.openpty()
        tty.setraw(master)
        self.device = os.ttyname(slave)
        os.close(slave)  # the controller opens it by name, as it would a real adapter
        self._master = master
        if self.link_path:
            _replace_symlink(self.device, self.link_path)
        return self.device

    def start(self) -> str:
        """Open the pty and serve it from a background thread; return the slave path."""
        device = self.open()
        self._stop.clear()
        self._thread = threading.Thread(target=self.serve_forever, args=(self._stop,),
                                        name=f"serial-sim {device}", daemon=True)
        self._thread.start()
        return device

    def stop(self) -> None:
        """Stop serving, close the pty and remove the symlink."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._master is not None:
            os.close(self._master)
            self._master = None
        if self.link_path:
            p = Path(self.link_path)
            if p.is_symlink() and os.readlink(p) == self.device:
                p.unlink()

    def __enter__(self) -> SerialSimFirmware:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def serve_forever(self, stop_event: threading.Event) -> None:
        """Answer requests until ``stop_event`` is set (opens the pty if needed)."""
        if self._master is None:
            self.open()
        master = self._master
        decoder = Decoder()
        while not stop_event.is_set():
            ready, _, _ = select.select([master], [], [], _POLL_S)
            if not ready:
                continue
            try:
                data = os.read(master, 4096)
            except OSError as exc:
                if exc.errno != errno.EIO:
                    raise
                decoder.reset()  # no one has the slave open: wait for the next opener
                stop_event.wait(_NO_PEER_S)
                continue
            for frame in decoder.feed(data):
                reply = self.handle(frame)
                if reply is not None:
                    try:
                        os.write(master, reply)
                    except OSError:
                        self.stats["write_failed"] += 1
            for reason, n in decoder.counts.items():
                self.stats[f"rejected_{reason}"] += n
            decoder.counts.clear()

    # -- fault hooks ------------------------------------------------------------------------
    def power_cycle(self, address: int) -> None:
        """Restart one controller: physics power cycle plus a forgotten duplicate cache."""
        with self._lock:
            self.controllers[address].power_cycle()
            self._cache.pop(address, None)

    # -- protocol ---------------------------------------------------------------------------
    def handle(self, frame: Frame) -> bytes | None:
        """The wire reply to one decoded frame, or None when the firmware stays silent
        (replies of other units, addresses it does not serve)."""
        if frame.command & REPLY_BIT or frame.address not in self.controllers:
            self.stats["ignored"] += 1
            return None
        self.stats["requests"] += 1
        key = (frame.seq, frame.command, frame.payload)
        with self._lock:
            cached = self._cache.get(frame.address)
            if cached is not None and cached[0] == key:
                self.stats["duplicates"] += 1
                return cached[1]
            try:
                payload = self._execute(self.controllers[frame.address], frame)
            except (struct.error, ValueError, OverflowError) as exc:
                # A reply that cannot be built (e.g. a value beyond the wire type) must not kill
                # the serving thread: the unit answers INTERNAL and keeps serving.
                self.stats["internal_errors"] += 1
                self.last_error = f"command 0x{frame.command:02x}: {exc}"
                payload = nak(Reject.INTERNAL)
            reply = encode(Frame(frame.address, frame.seq, frame.command | REPLY_BIT, payload))
            self._cache[frame.address] = (key, reply)
            return reply

    @staticmethod
    def _execute(ctl: SimController, frame: Frame) -> bytes:
        try:
            cmd = Command(frame.command)
        except ValueError:
            return nak(Reject.UNKNOWN_COMMAND)
        p = frame.payload
        if cmd == Command.PING:
            return ack(p) if len(p) <= MAX_PING else nak(Reject.BAD_LENGTH)
        if len(p) != REQUEST_LENGTH[cmd]:
            return nak(Reject.BAD_LENGTH)
        if cmd == Command.GET_STATUS:
            s = ctl.status()
            return ack(Status(s["az_steps"], s["az_target"], s["el_steps"], s["el_target"],
                              s["moving"], s["in_position"], s["limit_az"], s["limit_el"],
                              s["faults"]).pack())
        if cmd == Command.GET_INFO:
            return ack(Info(PROTOCOL_VERSION, 2, ctl.az.hard_min, ctl.az.hard_max, ctl.el.hard_min,
                            ctl.el.hard_max, ctl.firmware_version).pack())
        if cmd == Command.GET_LIMITS:
            return ack(LIMITS.pack(ctl.az.soft_min, ctl.az.soft_max, ctl.el.soft_min, ctl.el.soft_max))
        if cmd == Command.JOG:
            result = ctl.jog(*PAIR.unpack(p))
            if result != Reject.OK:
                return nak(result)
            return ack(PAIR.pack(ctl.axes["az"].target, ctl.axes["el"].target))
        if cmd == Command.MOVE_ABS:
            result = ctl.move_abs(*PAIR.unpack(p))
        elif cmd == Command.SET_LIMITS:
            result = ctl.set_limits(*LIMITS.unpack(p))
        else:
            result = {Command.STOP: ctl.stop, Command.HOME: ctl.home, Command.STOW: ctl.stow,
                      Command.CLEAR_FAULT: ctl.clear_fault}[cmd]()
        return ack() if result == Reject.OK else nak(result)


def _replace_symlink(target: str, link_path: str) -> None:
    """Point ``link_path`` at ``target`` atomically; refuse to replace anything but a symlink."""
    link = Path(link_path)
    if link.exists() and not link.is_symlink():
        raise FileExistsError(f"{link} exists and is not a symlink; refusing to replace it")
    link.parent.mkdir(parents=True, exist_ok=True)
    tmp = link.with_name(f".{link.name}.{os.getpid()}.tmp")
    tmp.unlink(missing_ok=True)
    os.symlink(target, tmp)
    os.replace(tmp, link)
