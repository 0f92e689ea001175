"""One GigE Vision imager through Aravis 0.8 (PyGObject): open, configure, stream frames.

Aravis is imported inside functions, so this package imports on machines without it; the
first call that needs it raises :class:`CameraError` naming what to install.

An imager streams into a fixed pool of ``buffers`` buffers: :meth:`GigeImager.next_frame`
pops one (with a timeout), copies the pixels out and pushes it back at once, so the pool
never shrinks however many frames are taken. Frames are 2-D ``uint8`` (Mono8) or ``uint16``
(Mono12, Mono16; 12-bit values are unpacked into 16-bit words by the camera).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from controller.devices.camera import CameraError
from controller.devices.cores import all_cores

PIXEL_DTYPES = {"Mono8": np.uint8, "Mono12": np.uint16, "Mono16": np.uint16}
SUPPORTED_FORMATS = tuple(PIXEL_DTYPES)
FAKE_PREFIX = "Fake_"  # ids of Aravis's in-process simulated device (its "Fake" interface)
RELEASE_WAIT_S = 15.0  # a lost handle's release: its GVCP commands' retries, about 10 s
CONTROL_RETRY_S = 0.25  # between attempts to take a control channel another controller holds
# Handles of lost imagers being released on a background thread, by device id: an imager opened
# again waits for its old handle to let go of the control channel first.
_RELEASING: dict[str, threading.Thread] = {}


class IncompleteFrame(CameraError):
    """A frame arrived with packets missing (or another stream fault); the device is fine."""


def aravis():
    """The Aravis 0.8 GObject module (imported on first use)."""
    try:
        import gi

        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis
    except (ImportError, ValueError) as exc:
        raise CameraError(f"GigE camera: Aravis 0.8 is not available ({exc}); install the Debian "
                          "package gir1.2-aravis-0.8 and the Python package PyGObject") from None
    return Aravis


def glib_error():
    from gi.repository import GLib

    return GLib.Error


def discovered_devices(enable_fake: bool = False) -> list[str]:
    """``"id (address)"`` of every device Aravis finds now (GigE discovery broadcasts)."""
    arv = aravis()
    if enable_fake:
        arv.enable_interface("Fake")
    arv.update_device_list()
    return [f"{arv.get_device_id(i)} ({arv.get_device_address(i)})" for i in range(arv.get_n_devices())]


@dataclass(frozen=True)
class Frame:
    """One frame: pixels (rows, cols), device timestamp (ns, device clock), frame id."""

    image: np.ndarray
    timestamp_ns: int
    frame_id: int


@dataclass(frozen=True)
class ImagerSettings:
    """What :class:`GigeImager` sets on open. ``exposure_s`` in seconds; ``gain`` in device
    units or None; ``roi`` (OffsetX, OffsetY, Width, Height) in pixels; ``trigger`` is
    ``software``, ``free`` or ``LineN``."""

    pixel_format: str
    exposure_s: float
    gain: float | None
    roi: tuple[int, int, int, int]
    trigger: str
    frame_rate_hz: float
    buffers: int
    packet_size: int | None


class GigeImager:
    """One opened, configured and streaming imager. ``role`` (LOW/HIGH) names it in messages."""

    def __init__(self, device_id: str, role: str, settings: ImagerSettings, *, discover: bool = True) -> None:
        # Aravis starts its threads here (the device's heartbeat, the stream's receiver): they
        # inherit the opening thread's cores and must never share Python's one core.
        with all_cores():
            self._open(device_id, role, settings, discover)

    def _open(self, device_id: str, role: str, settings: ImagerSettings, discover: bool) -> None:
        if settings.pixel_format not in PIXEL_DTYPES:
            raise CameraError(f"GigE camera: pixel format {settings.pixel_format!r} is not supported "
                              f"(supported: {', '.join(SUPPORTED_FORMATS)})")
        self.device_id = device_id
        self.role = role
        self.settings = settings
        self.lost = False
        self._dtype = PIXEL_DTYPES[settings.pixel_format]
        arv = aravis()
        error = glib_error()
        fake = device_id.startswith(FAKE_PREFIX)
        if fake:
            arv.enable_interface("Fake")
        # Discovery first (about 1 s): it records which interface reaches the device, and the
        # stream is sent there (opened blind, a loopback device streams to the wrong address).
        if discover:
            arv.update_device_list()
        try:
            self._cam = arv.Camera.new(device_id)
        except error as exc:
            found = discovered_devices(fake)
            raise CameraError(f"GigE camera: {role} imager {device_id!r} not found ({exc.message}); "
                              f"devices found: {', '.join(found) if found else 'none'}") from None
        self._stream = None
        try:
            self._device = self._cam.get_device()
            if isinstance(self._device, arv.GvDevice):
                self._take_control(self._device)
            self._lost_handler = self._device.connect("control-lost", self._on_control_lost)
            self._configure(arv)
            self._start(arv)
        except error as exc:
            self.close()
            raise CameraError(f"GigE camera: {role} imager {device_id!r}: {exc.message}") from None
        except CameraError:
            self.close()
            raise

    def _take_control(self, device) -> None:
        """Hold the control channel, or say who has it. Aravis opens a device whose channel it
        could not take without a word: the writes that follow are refused, or — once the other
        controller lets go — land while nobody holds the channel, and the device then ignores
        every trigger. The channel is waited for while our own handle lost before is released,
        then for as long as another controller's heartbeat can hold it."""
        if device.is_controller():
            return
        pending = _RELEASING.get(self.device_id)
        if pending is not None:  # a device that is away fails to open before this wait
            pending.join(RELEASE_WAIT_S)
        deadline = time.monotonic() + _heartbeat_timeout_s(device) + CONTROL_RETRY_S
        while not device.is_controller():
            if time.monotonic() > deadline:
                raise self._fail("another application holds its control channel (GigE Vision CCP): "
                                 "close it, or wait until its heartbeat times out")
            time.sleep(CONTROL_RETRY_S)
            try:
                device.take_control()
            except glib_error():
                pass  # still held: the loop's deadline decides

    def _on_control_lost(self, _device) -> None:
        # Emitted from Aravis's heartbeat thread; only a flag is set here.
        self.lost = True

    def _fail(self, what: str) -> CameraError:
        return CameraError(f"GigE camera: {self.role} imager {self.device_id!r}: {what}")

    def _configure(self, arv) -> None:
        cam, s = self._cam, self.settings
        offered = list(cam.dup_available_pixel_formats_as_strings())
        if s.pixel_format not in offered:
            raise self._fail(f"pixel format {s.pixel_format} is not offered by the device (it offers "
                             f"{', '.join(offered)}; heliocal supports {', '.join(SUPPORTED_FORMATS)})")
        cam.set_pixel_format_from_string(s.pixel_format)
        sensor = cam.get_sensor_size()
        x, y, w, h = s.roi
        if x + w > sensor.width or y + h > sensor.height:
            raise self._fail(f"ROI {w}x{h} at ({x}, {y}) exceeds the {sensor.width}x{sensor.height} sensor")
        cam.set_region(x, y, w, h)
        got = cam.get_region()
        if (got.x, got.y, got.width, got.height) != (x, y, w, h):
            raise self._fail(f"ROI {w}x{h} at ({x}, {y}) was set to {got.width}x{got.height} at "
                             f"({got.x}, {got.y}) (the device's increments)")
        self.set_exposure(s.exposure_s)
        if s.gain is not None:
            bounds = cam.get_gain_bounds()
            if not bounds.min <= s.gain <= bounds.max:
                raise self._fail(f"gain {s.gain} is outside the device's range [{bounds.min}, {bounds.max}]")
            cam.set_gain(s.gain)
        cam.set_acquisition_mode(arv.AcquisitionMode.CONTINUOUS)
        if s.trigger == "free":
            cam.clear_triggers()
            cam.set_frame_rate(s.frame_rate_hz)
        else:
            source = "Software" if s.trigger == "software" else s.trigger
            sources = list(cam.dup_available_trigger_sources())
            if source not in sources:
                raise self._fail(f"trigger source {source} is not offered (it offers {', '.join(sources)})")
            cam.set_trigger(source)  # TriggerSelector FrameStart, TriggerMode On, TriggerSource
        if s.packet_size is not None and cam.is_gv_device():
            cam.gv_set_packet_size(s.packet_size)

    def _start(self, arv) -> None:
        self._stream = self._cam.create_stream(None, None)
        if self._stream is None:
            raise self._fail("could not create the stream")
        payload = self._cam.get_payload()
        for _ in range(self.settings.buffers):
            self._stream.push_buffer(arv.Buffer.new_allocate(payload))
        self._cam.start_acquisition()

    # -- control ----------------------------------------------------------------------------

    def set_exposure(self, seconds: float) -> float:
        """Set ExposureTime; returns what the device took (s). Out of range: CameraError."""
        bounds = self._cam.get_exposure_time_bounds()  # microseconds
        us = seconds * 1e6
        if not bounds.min <= us <= bounds.max:
            raise self._fail(f"exposure {seconds:g} s is outside the device's range "
                             f"[{bounds.min / 1e6:g}, {bounds.max / 1e6:g}] s")
        self._guarded(lambda: self._cam.set_exposure_time(us), "set the exposure")
        return self.exposure_s()

    def exposure_s(self) -> float:
        return self._guarded(self._cam.get_exposure_time, "read the exposure") / 1e6

    def feature(self, name: str) -> str:
        """A GenICam feature's value as a string (for tests and diagnostics)."""
        return self._guarded(lambda: self._device.get_feature(name).get_value_as_string(),
                             f"read feature {name}")

    def gain(self) -> float:
        return self._guarded(self._cam.get_gain, "read the gain")

    def has_command(self, name: str) -> bool:
        """Whether the device implements the GenICam command ``name``."""
        try:
            device = self._device
            return device.get_feature(name) is not None and bool(device.is_feature_available(name))
        except glib_error():
            return False

    def execute(self, name: str) -> None:
        self._guarded(lambda: self._device.execute_command(name), f"execute {name}")

    def trigger(self) -> None:
        """Send the TriggerSoftware command."""
        self._guarded(self._cam.software_trigger, "send the software trigger")

    def _guarded(self, call, what: str):
        try:
            return call()
        except glib_error() as exc:
            self.lost = True
            raise self._fail(f"lost: could not {what} ({exc.message}); the next capture reopens it") from None

    # -- frames -----------------------------------------------------------------------------

    def drain(self) -> int:
        """Return every frame already delivered to the pool (stale); how many there were."""
        n = 0
        while (buf := self._stream.try_pop_buffer()) is not None:
            self._stream.push_buffer(buf)
            n += 1
        return n

    def next_frame(self, timeout_s: float) -> Frame:
        """The next complete frame, waiting at most ``timeout_s``."""
        arv = aravis()
        buf = self._stream.timeout_pop_buffer(int(timeout_s * 1e6))
        if buf is None:
            if self.lost or not self._answers():
                self.lost = True
                raise self._fail("lost: the device stopped answering; the next capture reopens it")
            raise self._fail(f"no frame within {timeout_s * 1e3:g} ms (trigger {self.settings.trigger})")
        try:
            status = buf.get_status()
            if status != arv.BufferStatus.SUCCESS:
                raise IncompleteFrame(f"GigE camera: {self.role} imager {self.device_id!r}: incomplete "
                                      f"frame ({status.value_nick})")
            h, w = buf.get_image_height(), buf.get_image_width()
            image = np.frombuffer(buf.get_data(), dtype=self._dtype, count=h * w).reshape(h, w).copy()
            return Frame(image, int(buf.get_timestamp()), int(buf.get_frame_id()))
        finally:
            self._stream.push_buffer(buf)

    def _answers(self) -> bool:
        try:
            self._cam.get_payload()
            return True
        except glib_error():
            return False

    def buffer_counts(self) -> tuple[int, int]:
        """(buffers waiting for a frame, frames waiting to be popped): the pool's size split."""
        n_in, n_out = self._stream.get_n_buffers()
        return int(n_in), int(n_out)

    @property
    def is_gv(self) -> bool:
        return bool(self._cam.is_gv_device())

    def close(self) -> None:
        """Stop acquisition and release the stream and device.

        Releasing a lost device still sends it GVCP commands (stop the stream channel, leave
        control), each waiting out its retries: about 10 s in all. That happens on a
        background thread, so a lost imager is reported at once."""
        cam, stream, device = getattr(self, "_cam", None), self._stream, getattr(self, "_device", None)
        self._stream = self._cam = self._device = None
        if cam is None:
            return
        if getattr(self, "_lost_handler", None) is not None:
            device.disconnect(self._lost_handler)
            self._lost_handler = None
        if self.lost:
            release = _background_release((stream, cam, device), self.device_id)
            del stream, cam, device  # the wrappers go first, so the thread holds the last references
            release()
            return
        try:
            cam.stop_acquisition()
        except glib_error():
            pass  # gone after all; the stream and sockets are freed all the same


def _heartbeat_timeout_s(device) -> float:
    """How long the device keeps a silent controller's channel (GevHeartbeatTimeout, ms; the
    standard's default of 3 s when the device does not say)."""
    try:
        return device.get_integer_feature_value("GevHeartbeatTimeout") / 1e3
    except glib_error():
        return 3.0


def _background_release(objects: tuple, name: str):
    """Take a GObject reference to each of ``objects``; the returned function starts a thread
    that drops them. Call it once the caller has dropped its Python wrappers, so the thread's
    references are the last: PyGObject finalizes an object holding the GIL, which would stall
    every thread for the finalizer's GVCP timeouts, while a ctypes call releases the GIL. The
    thread is listed in ``_RELEASING`` under ``name`` (the device id) until it is done."""
    import ctypes
    import ctypes.util

    gobject = ctypes.CDLL(ctypes.util.find_library("gobject-2.0"))
    gobject.g_object_ref.argtypes = [ctypes.c_void_p]
    gobject.g_object_ref.restype = ctypes.c_void_p
    gobject.g_object_unref.argtypes = [ctypes.c_void_p]
    pointer = ctypes.pythonapi.PyCapsule_GetPointer
    pointer.restype = ctypes.c_void_p
    pointer.argtypes = [ctypes.py_object, ctypes.c_char_p]
    addresses = [gobject.g_object_ref(pointer(o.__gpointer__, None)) for o in objects if o is not None]

    def release() -> None:
        for address in addresses:
            gobject.g_object_unref(address)
        if _RELEASING.get(name) is thread:  # not a later loss's release of the same device
            del _RELEASING[name]

    thread = threading.Thread(target=release, daemon=True, name=f"release-{name}")

    def start() -> None:
        _RELEASING[name] = thread
        thread.start()

    return start
