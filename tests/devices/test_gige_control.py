"""The GigE Vision control channel (CCP) as the driver takes it, against the simulated plant's
imager server on a loopback address of its own: a device another controller holds is refused
with a clear error, and one whose holder lets go while the driver waits is taken and streams.

Aravis alone opens a device it could not take control of without a word; the writes that
follow then fail, or land while nobody holds the channel and the device ignores every trigger
(a capture that waits out its whole timeout)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from controller.devices.camera import CameraError
from controller.devices.gige_device import GigeImager, ImagerSettings
from tests.conftest import aravis_missing, scaled_s

IMAGE = np.arange(48 * 64, dtype=np.uint16).reshape(48, 64) % 4096


MISSING = aravis_missing()
if MISSING:
    print(f"tests/devices/test_gige_control.py: skipping: {MISSING}")


def _settings() -> ImagerSettings:
    return ImagerSettings(pixel_format="Mono16", exposure_s=0.01, gain=None, roi=(0, 0, 64, 48),
                          trigger="software", frame_rate_hz=30.0, buffers=4, packet_size=None)


@pytest.fixture
def server():
    if MISSING:
        pytest.skip(MISSING)
    from simplant.devices.gige_plant import serve_imager

    s = serve_imager("ccp-test", lambda: (IMAGE, time.time_ns()))
    yield s
    s.stop()


def _frame(imager: GigeImager) -> np.ndarray:
    imager.drain()
    imager.trigger()
    return imager.next_frame(scaled_s(5)).image


def test_a_device_another_controller_holds_is_refused_and_the_holder_keeps_streaming(server):
    first = GigeImager(server.address, "LOW", _settings(), discover=False)
    try:
        with pytest.raises(CameraError, match=rf"HIGH imager '{server.address}': another application holds "
                                              r"its control channel \(GigE Vision CCP\)"):
            GigeImager(server.address, "HIGH", _settings(), discover=False)
        assert server.refused >= 1
        np.testing.assert_array_equal(_frame(first), IMAGE)
    finally:
        first.close()


def test_a_device_let_go_while_the_driver_waits_is_taken_and_streams(server):
    first = GigeImager(server.address, "LOW", _settings(), discover=False)
    opened: dict = {}

    def open_second() -> None:
        try:
            opened["imager"] = GigeImager(server.address, "HIGH", _settings(), discover=False)
        except CameraError as exc:
            opened["error"] = exc

    t = threading.Thread(target=open_second)
    try:
        t.start()
        # The holder lets go only once the device has refused the second controller's claim.
        deadline = time.monotonic() + scaled_s(10)
        while server.refused == 0 and t.is_alive() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert server.refused >= 1, opened
    finally:
        first.close()
        t.join(scaled_s(10))
    second = opened.get("imager")
    assert second is not None, opened
    try:
        np.testing.assert_array_equal(_frame(second), IMAGE)
    finally:
        second.close()


def test_an_imager_reopened_after_a_loss_takes_the_channel_its_old_handle_held(server):
    first = GigeImager(server.address, "LOW", _settings(), discover=False)
    first.lost = True  # as after a GVCP timeout: its handle is released on a background thread
    first.close()
    second = GigeImager(server.address, "LOW", _settings(), discover=False)
    try:
        np.testing.assert_array_equal(_frame(second), IMAGE)
    finally:
        second.close()
