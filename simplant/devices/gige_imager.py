"""One GigE Vision imager of the simulated plant, on a loopback address of its own.

GigE Vision fixes a device's control port (GVCP, UDP 3956), so every imager needs an address of
its own; Aravis's ``arv-fake-gv-camera-0.8`` binds only an address a network interface has
(127.0.0.1 on the loopback), which gives one device per machine, and streams its own test
pattern. This server is its socket layer for any loopback address (127.0.0.2 and up: Linux
routes all of 127.0.0.0/8 to the loopback) over the same device model: Aravis's fake camera
(``ArvFakeCamera``: the GenICam XML and registers ``arv-fake-gv-camera-0.8`` serves), with
frames from a callback — the simulated plant's renders — instead of its pattern.

What it speaks (GigE Vision 1.x, as the fake): GVCP discovery, register and memory reads and
writes, with the control channel owned by one controller until it releases it or its
heartbeat times out; GVSP leader, payload and trailer packets of the configured packet size
to the stream address the controller wrote, for each software trigger while acquisition is
on, and packet resends on request. Only software triggers produce frames.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import logging
import queue
import re
import socket
import struct
import threading
import time
from collections.abc import Callable

import numpy as np

from controller.devices import gige_device

GVCP_PORT = 3956
_DISCOVERY, _PACKET_RESEND = 0x0002, 0x0040
_READ_REG, _WRITE_REG, _READ_MEM, _WRITE_MEM = 0x0080, 0x0082, 0x0084, 0x0086
_DISCOVERY_SIZE = 0xF8  # bootstrap registers a discovery answer carries
_SCPS0 = 0x0D04  # bootstrap register: stream channel 0's packet size (low 16 bits)
_GVCP_CAPABILITY, _PACKET_RESEND_SUPPORTED = 0x0934, 1 << 2  # bootstrap register and its bit
_ACCESS_DENIED = 0x8006  # GVCP status of a write from a host without the control channel
_GVSP_OVERHEAD = 20 + 8 + 8  # IP, UDP and GVSP headers within a packet size
_LEADER, _TRAILER, _PAYLOAD = 1, 2, 3
_PIXEL_FORMATS = {0x01080001: np.uint8, 0x01100007: np.uint16}  # Mono8, Mono16
_KEPT_FRAMES = 4  # frames whose packets are kept for resend requests
_log = logging.getLogger(__name__)


def aravis():
    """Aravis 0.8 through PyGObject, as the product's GigE driver loads it (a CameraError saying
    what to install when it is missing)."""
    return gige_device.aravis()


class GigeImagerServer:
    """A GigE Vision imager at ``address`` (port 3956) with serial ``serial``; each software
    trigger streams ``frame()``: (image, device timestamp in ns). :meth:`start` binds and
    serves (OSError when the address is taken); :meth:`stop` ends it."""

    def __init__(self, address: str, serial: str, frame: Callable[[], tuple[np.ndarray, int]]) -> None:
        from gi.repository import Gio

        arv = aravis()
        self.address = address
        self.serial = serial
        self._frame = frame
        self._fake = arv.FakeCamera.new(serial)
        self._fake.set_inet_address(Gio.InetAddress.new_from_string(address))
        # Unlike the fake's own socket layer, this one resends lost packets: say so.
        self._fake.write_register(_GVCP_CAPABILITY, self._fake.read_register(_GVCP_CAPABILITY)[1]
                                  | _PACKET_RESEND_SUPPORTED)
        self._pointer = _gpointer(self._fake)
        self._registers = _register_addresses(self._fake.get_genicam_xml()[0])
        self._lock = threading.Lock()  # the device model: GVCP and stream threads share it
        self._controller: tuple | None = None
        self.refused = 0  # writes refused to a host without the control channel
        self._controller_seen = 0.0
        self._triggers: queue.Queue = queue.Queue()
        self._sent: dict[int, list[bytes]] = {}  # the last frames' packets by block id, for resends
        self._destination: tuple[str, int] | None = None
        self._block = 0
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._gvcp: socket.socket | None = None
        self._gvsp: socket.socket | None = None

    # -- lifecycle ------------------------------------------------------------------------
    def start(self) -> None:
        gvcp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            gvcp.bind((self.address, GVCP_PORT))
        except OSError:
            gvcp.close()
            raise
        gvcp.settimeout(0.1)
        self._gvcp = gvcp
        self._gvsp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._gvsp.bind((self.address, 0))
        for name, target in (("gvcp", self._serve_control), ("gvsp", self._serve_stream)):
            t = threading.Thread(target=target, name=f"gige-{self.address}-{name}", daemon=True)
            t.start()
            self._threads.append(t)

    def stop(self) -> None:
        self._stop.set()
        self._triggers.put(None)
        for t in self._threads:
            t.join(timeout=5)
        self._threads.clear()
        for s in (self._gvcp, self._gvsp):
            if s is not None:
                s.close()
        self._gvcp = self._gvsp = None

    # -- the device model -----------------------------------------------------------------
    def register(self, name: str) -> int:
        """The value of a register the fake's GenICam XML names (e.g. ``ExposureTimeAbsRegister``)."""
        return self.register_at(self._registers[name])

    def register_at(self, address: int) -> int:
        with self._lock:
            return int(self._fake.read_register(address)[1])

    def exposure_s(self) -> float:
        """The exposure the controller set (ExposureTimeAbs, µs), in s."""
        return self.register("ExposureTimeAbsRegister") / 1e6

    def _read_memory(self, address: int, size: int) -> bytes:
        buf = ctypes.create_string_buffer(size)
        _libaravis().arv_fake_camera_read_memory(self._pointer, address, size, buf)
        return buf.raw

    def _write_memory(self, address: int, data: bytes) -> None:
        buf = ctypes.create_string_buffer(data, len(data))
        _libaravis().arv_fake_camera_write_memory(self._pointer, address, len(data), buf)

    # -- GVCP -----------------------------------------------------------------------------
    def _serve_control(self) -> None:
        while not self._stop.is_set():
            try:
                packet, remote = self._gvcp.recvfrom(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            if len(packet) < 8 or packet[0] != 0x42:
                continue
            _, _, command, length, request = struct.unpack(">BBHHH", packet[:8])
            answer = self._command(command, packet[8:8 + length], remote)
            if answer is not None:
                status, ack, body = answer
                self._gvcp.sendto(struct.pack(">HHHH", status, ack, len(body), request) + body, remote)

    def _command(self, command: int, body: bytes, remote: tuple) -> tuple[int, int, bytes] | None:
        with self._lock:
            writes = self._access(remote)
            fake = self._fake
            if command == _DISCOVERY:
                return 0, command + 1, self._read_memory(0, _DISCOVERY_SIZE)
            if command == _READ_REG:
                addresses = struct.unpack(f">{len(body) // 4}I", body[: len(body) // 4 * 4])
                values = [fake.read_register(a)[1] for a in addresses]
                return 0, command + 1, struct.pack(f">{len(values)}I", *values)
            if command == _READ_MEM:
                address, _, size = struct.unpack(">IHH", body[:8])
                return 0, command + 1, struct.pack(">I", address) + self._read_memory(address, size)
            if command == _PACKET_RESEND:
                self._resend(*struct.unpack(">III", body[:12]))
                return None
            if command not in (_WRITE_REG, _WRITE_MEM):
                return None
            if not writes:
                self.refused += 1
                return _ACCESS_DENIED, command + 1, struct.pack(">HH", 0, 0)
            if command == _WRITE_REG:
                pairs = [struct.unpack(">II", body[i:i + 8]) for i in range(0, len(body) - 7, 8)]
                for address, value in pairs:
                    fake.write_register(address, value)
                done = len(pairs)
            else:
                self._write_memory(struct.unpack(">I", body[:4])[0], body[4:])
                done = len(body) - 4
            self._claim(remote)
            if fake.check_and_acknowledge_software_trigger():
                self._triggers.put(True)
            return 0, command + 1, struct.pack(">HH", 0, done & 0xFFFF)

    def _access(self, remote: tuple) -> bool:
        """Whether ``remote`` may write: no controller, or it is the controller (whose heartbeat
        counts), or the controller's heartbeat has timed out (it is released)."""
        now = time.monotonic()
        if self._controller is not None and self._controller != remote:
            if now - self._controller_seen <= self._fake.get_heartbeat_timeout() / 1e3:
                return False
            self._controller = None
            self._fake.set_control_channel_privilege(0)
        if self._controller == remote:
            self._controller_seen = now
        return True

    def _claim(self, remote: tuple) -> None:
        """After a write: the writer took the control channel, or gave it back."""
        privileged = self._fake.get_control_channel_privilege() != 0
        if self._controller is None and privileged:
            self._controller, self._controller_seen = remote, time.monotonic()
        elif self._controller is not None and not privileged:
            self._controller = None

    # -- GVSP -----------------------------------------------------------------------------
    def _serve_stream(self) -> None:
        while self._triggers.get() is not None:
            with self._lock:
                idle = ("no controller holds the control channel" if self._controller is None
                        else "acquisition is stopped" if self._fake.get_acquisition_status() == 0 else None)
                where = self._fake.get_stream_address()
            if idle:  # a camera ignores it; say so, as the controller will only see a timeout
                _log.warning("simulated GigE imager %s: a software trigger came while %s; no frame sent",
                             self.address, idle)
                continue
            try:
                image, timestamp_ns = self._frame()
                self._send(image, timestamp_ns, (where.get_address().to_string(), where.get_port()))
            except Exception as exc:  # noqa: BLE001 - a frame lost is what a camera does; say why
                _log.warning("simulated GigE imager %s: a triggered frame was not sent: %s: %s", self.address,
                             type(exc).__name__, exc)

    def _send(self, image: np.ndarray, timestamp_ns: int, destination: tuple[str, int]) -> None:
        """Stream ``image`` as one GVSP block: leader, payload packets, trailer."""
        width, height = self.register("WidthRegister"), self.register("HeightRegister")
        pixel_format = self.register("PixelFormatRegister")
        dtype = _PIXEL_FORMATS.get(pixel_format)
        if dtype is None or image.shape != (height, width) or image.dtype != dtype:
            raise ValueError(f"the controller asks for {width}x{height} pixel format {pixel_format:#x}; the "
                             f"plant renders {image.shape[1]}x{image.shape[0]} {image.dtype}")
        data = np.ascontiguousarray(image, dtype=np.dtype(dtype).newbyteorder("<")).tobytes()
        step = max(1, (self.register_at(_SCPS0) & 0xFFFF) - _GVSP_OVERHEAD)
        offsets = (self.register("OffsetXRegister"), self.register("OffsetYRegister"))
        chunks = [(_LEADER, struct.pack(">HHIIIIIIIHH", 0, 1, timestamp_ns >> 32, timestamp_ns & 0xFFFFFFFF,
                                        pixel_format, width, height, *offsets, 0, 0))]
        chunks += [(_PAYLOAD, data[i:i + step]) for i in range(0, len(data), step)]
        chunks.append((_TRAILER, struct.pack(">HHI", 0, 1, height)))
        self._block = self._block % 0xFFFF + 1
        packets = [struct.pack(">HHI", 0, self._block, (kind << 24) | k) + chunk
                   for k, (kind, chunk) in enumerate(chunks)]
        self._sent.pop(self._block, None)
        self._sent[self._block] = packets
        while len(self._sent) > _KEPT_FRAMES:
            del self._sent[next(iter(self._sent))]
        self._destination = destination
        for p in packets:
            self._gvsp.sendto(p, destination)

    def _resend(self, block: int, first: int, last: int) -> None:
        packets = self._sent.get(block & 0xFFFF)
        if packets is None or self._destination is None:
            return
        for p in packets[first & 0xFFFFFF: (last & 0xFFFFFF) + 1]:
            with contextlib.suppress(OSError):
                self._gvsp.sendto(p, self._destination)


def discover(address: str, timeout_s: float = 1.0) -> bool:
    """Whether a GigE Vision device at ``address`` answers a GVCP discovery (unicast)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.settimeout(timeout_s)
        s.sendto(struct.pack(">BBHHH", 0x42, 0x01, _DISCOVERY, 0, 1), (address, GVCP_PORT))
        try:
            answer = s.recv(1024)
        except TimeoutError:
            return False
    return len(answer) >= 8 and struct.unpack(">HH", answer[:4]) == (0, _DISCOVERY + 1)


def _register_addresses(xml: str) -> dict[str, int]:
    """Register name -> address, from a GenICam XML's register nodes."""
    found = re.findall(r'Name="(\w+)"[^>]*>(?:(?!Name=).)*?<Address>(0x[0-9a-fA-F]+|\d+)</Address>',
                       xml, re.S)
    return {name: int(address, 0) for name, address in found}


def _gpointer(obj) -> int:
    """The C pointer of a PyGObject object (for the fake's memory calls, which PyGObject cannot
    make: their buffers are untyped)."""
    get = ctypes.pythonapi.PyCapsule_GetPointer
    get.restype = ctypes.c_void_p
    get.argtypes = [ctypes.py_object, ctypes.c_char_p]
    return get(obj.__gpointer__, None)


@functools.cache
def _libaravis() -> ctypes.CDLL:
    lib = ctypes.CDLL("libaravis-0.8.so.0")
    for name in ("arv_fake_camera_read_memory", "arv_fake_camera_write_memory"):
        getattr(lib, name).argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32, ctypes.c_void_p]
        getattr(lib, name).restype = ctypes.c_bool
    return lib
