"""The double-CCD camera as two GigE Vision imagers (e.g. a JAI AD-081GE), through Aravis.

The prism camera shows up on the network as two independent GigE Vision devices; the plant
configuration names them (``camera.gige.low`` / ``.high``, docs/camera.md). One capture:

- ``trigger: software``: TriggerSoftware to LOW then HIGH, then one frame from each;
- ``trigger: LineN`` (hardware) or ``free`` (free-running at ``frame_rate_hz``): the next
  frame of each imager after the call (frames already waiting are stale and dropped).

The two frames' device timestamps (ns) must agree within ``max_skew_ms``, else the pair is
refused with a :class:`CameraError` naming both. Device clocks are only comparable when they
share an epoch: imagers that implement ``GevTimestampControlReset`` get it on open and every
``CLOCK_RESYNC_S`` (a few ppm of drift between two crystals is ms per quarter hour), back to
back, so their clocks differ by about one control round trip; imagers that do not implement it
must already share a clock (PTP, or one camera body).

A lost imager (no answer, control lost, stream failure) raises a CameraError that says so;
the camera then closes both imagers and the next :meth:`GigeCamera.capture` reopens them.
"""

from __future__ import annotations

import time

from controller.config import Camera
from controller.devices.camera import CameraError, DoubleCcdCamera, FramePair
from controller.devices.gige_device import (
    FAKE_PREFIX,
    GigeImager,
    ImagerSettings,
    IncompleteFrame,
    discovered_devices,
    glib_error,
)

CLOCK_RESYNC_S = 10.0
PAIR_ATTEMPTS = 3  # a pair with an incomplete frame (lost GVSP packets) is taken again
RESET_FEATURE = "GevTimestampControlReset"


class GigeCamera(DoubleCcdCamera):
    """A :class:`DoubleCcdCamera` on two GigE Vision imagers; ``cfg.driver`` must be gige."""

    def __init__(self, cfg: Camera) -> None:
        if cfg.gige is None:
            raise CameraError("GigE camera: the configuration has no camera.gige section")
        self.cfg = cfg
        self.gige = cfg.gige
        self._exposures = (cfg.sensors[0].exposure_s, cfg.sensors[1].exposure_s)
        self._imagers: tuple[GigeImager, GigeImager] | None = None
        self._clock_sync = "none"
        self._synced_at = 0.0
        self.reopened = 0  # how many times a lost camera was opened again
        self._open()

    # -- lifecycle ---------------------------------------------------------------------------

    def _settings(self, exposure_s: float) -> ImagerSettings:
        g, c = self.gige, self.cfg
        return ImagerSettings(
            pixel_format=c.gige_pixel_format(), exposure_s=exposure_s, gain=g.gain,
            roi=(g.roi_offset_px[0], g.roi_offset_px[1], c.width_px, c.height_px), trigger=g.trigger,
            frame_rate_hz=g.frame_rate_hz, buffers=g.buffers, packet_size=g.packet_size)

    def _open(self) -> None:
        discovered_devices(any(i.startswith(FAKE_PREFIX) for i in (self.gige.low, self.gige.high)))
        low = GigeImager(self.gige.low, "LOW", self._settings(self._exposures[0]), discover=False)
        try:
            high = GigeImager(self.gige.high, "HIGH", self._settings(self._exposures[1]), discover=False)
        except CameraError:
            low.close()
            raise
        self._imagers = (low, high)
        self._exposures = (low.exposure_s(), high.exposure_s())
        self._sync_clocks()

    def _sync_clocks(self) -> None:
        low, high = self._imagers
        if not all(i.has_command(RESET_FEATURE) for i in (low, high)):
            return
        low.execute(RESET_FEATURE)
        high.execute(RESET_FEATURE)
        self._clock_sync = "reset"
        self._synced_at = time.monotonic()

    def close(self) -> None:
        if self._imagers is not None:
            for imager in self._imagers:
                imager.close()
            self._imagers = None

    def _lost(self, exc: CameraError) -> CameraError:
        """Close both imagers so the next capture reopens them; return the error to raise."""
        self.close()
        return exc

    # -- DoubleCcdCamera ---------------------------------------------------------------------

    @property
    def exposures(self) -> tuple[float, float]:
        """(t_low, t_high) in seconds, as the devices took them."""
        return self._exposures

    def set_exposures(self, t_low: float, t_high: float) -> None:
        if not 0 < t_low <= t_high:
            raise CameraError(f"GigE camera: exposures must satisfy 0 < t_low <= t_high, got "
                              f"({t_low:g}, {t_high:g}) s")
        if self._imagers is None:
            self._exposures = (float(t_low), float(t_high))  # applied when the camera reopens
            return
        low, high = self._imagers
        try:
            self._exposures = (low.set_exposure(t_low), high.set_exposure(t_high))
        except CameraError as exc:
            if low.lost or high.lost:
                raise self._lost(exc) from None
            raise

    def capture(self) -> FramePair:
        if self._imagers is None:
            self._open()
            self.reopened += 1
        low, high = self._imagers
        attempt = 1
        while True:
            try:
                return self._capture_once(low, high, attempt)
            except IncompleteFrame:
                if attempt == PAIR_ATTEMPTS:
                    raise
                attempt += 1

    def _capture_once(self, low: GigeImager, high: GigeImager, attempt: int) -> FramePair:
        timeout = self.gige.timeout_ms / 1e3
        try:
            if self._clock_sync == "reset" and time.monotonic() - self._synced_at > CLOCK_RESYNC_S:
                self._sync_clocks()
            stale = low.drain() + high.drain()
            if self.gige.trigger == "software":
                low.trigger()
                high.trigger()
            f_low = low.next_frame(timeout)
            f_high = high.next_frame(timeout)
        except IncompleteFrame:
            raise
        except CameraError as exc:
            if low.lost or high.lost:
                raise self._lost(exc) from None
            raise
        except glib_error() as exc:  # a stream or control call the imager did not wrap
            raise self._lost(CameraError(f"GigE camera: {exc.message}")) from None
        skew_ms = abs(f_low.timestamp_ns - f_high.timestamp_ns) / 1e6
        if skew_ms > self.gige.max_skew_ms:
            raise CameraError(
                f"GigE camera: frame pair refused: LOW {low.device_id!r} frame {f_low.frame_id} at "
                f"{f_low.timestamp_ns} ns and HIGH {high.device_id!r} frame {f_high.frame_id} at "
                f"{f_high.timestamp_ns} ns are {skew_ms:.3f} ms apart (max_skew_ms "
                f"{self.gige.max_skew_ms:g})")
        meta = {
            "driver": "gige", "devices": [low.device_id, high.device_id],
            "timestamps_ns": [f_low.timestamp_ns, f_high.timestamp_ns], "skew_ms": skew_ms,
            "frame_ids": [f_low.frame_id, f_high.frame_id], "pixel_format": self.cfg.gige_pixel_format(),
            "roi": list(low.settings.roi), "trigger": self.gige.trigger, "clock_sync": self._clock_sync,
            "stale_frames_dropped": stale, "attempts": attempt,
        }
        return FramePair(f_low.image, f_high.image, self._exposures, f_low.timestamp_ns / 1e9, meta)

    # -- diagnostics -------------------------------------------------------------------------

    @property
    def imagers(self) -> tuple[GigeImager, GigeImager]:
        """The open (LOW, HIGH) imagers; CameraError while closed after a loss."""
        if self._imagers is None:
            raise CameraError("GigE camera: closed after a lost imager; capture() reopens it")
        return self._imagers
