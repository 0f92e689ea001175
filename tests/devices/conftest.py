"""A real GigE Vision device on loopback: ``arv-fake-gv-camera-0.8 -i 127.0.0.1`` (Debian
aravis-tools) speaks GVCP/GVSP like a camera. A second imager comes from Aravis's in-process
simulated device (``Fake_1``), since only one GigE Vision device can own 127.0.0.1:3956.

The GVCP port is machine-wide, so a file lock lets one fake camera live at a time across the
test workers (pytest-xdist). Every process started here is killed in teardown.
"""

from __future__ import annotations

import fcntl
import itertools
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import pytest

from controller.config import Camera
from tests.conftest import scaled_s

FAKE_GV = "arv-fake-gv-camera-0.8"
_serials = itertools.count(1)


def _aravis_missing() -> str | None:
    if shutil.which(FAKE_GV) is None:
        return f"{FAKE_GV} not found (Debian package aravis-tools; .ci/run installs it)"
    try:
        import gi

        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis  # noqa: F401
    except (ImportError, ValueError) as exc:
        return (f"Aravis 0.8 through PyGObject is not importable ({exc}); "
                "install gir1.2-aravis-0.8 and PyGObject")
    return None


MISSING = _aravis_missing()
if MISSING:
    print(f"tests/devices: skipping GigE Vision tests: {MISSING}")


class FakeGvCamera:
    """One ``arv-fake-gv-camera-0.8`` process on 127.0.0.1 with a unique serial."""

    def __init__(self) -> None:
        self.serial = f"HC{os.getpid() % 100000}x{next(_serials)}"
        self.device_id = f"Aravis-Fake-{self.serial}"
        self.proc: subprocess.Popen | None = None

    def start(self) -> None:
        from controller.devices.gige_device import discovered_devices

        self.proc = subprocess.Popen([FAKE_GV, "-i", "127.0.0.1", "-s", self.serial],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        deadline = time.monotonic() + scaled_s(15)
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"{FAKE_GV} exited: {self.proc.stderr.read().decode(errors='replace')}")
            if any(d.startswith(self.device_id + " ") for d in discovered_devices()):
                self._check_owner()
                return
        raise RuntimeError(f"{self.device_id} was not discovered on 127.0.0.1")

    def _check_owner(self) -> None:
        """Control goes to whichever process owns 127.0.0.1:3956: make sure it is this one."""
        from gi.repository import Aravis

        cam = Aravis.Camera.new(self.device_id)
        answered = cam.get_device().get_string_feature_value("DeviceID")
        del cam
        if answered != self.serial:
            raise RuntimeError(f"another GigE Vision device ({answered}) owns 127.0.0.1:3956; stop it")

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)
        self.proc = None


@pytest.fixture
def fake_gv():
    if MISSING:
        pytest.skip(MISSING)
    lock = open(Path(tempfile.gettempdir()) / "heliocal-gvcp-3956.lock", "w")  # noqa: SIM115
    fcntl.flock(lock, fcntl.LOCK_EX)
    cam = FakeGvCamera()
    try:
        cam.start()
        yield cam
    finally:
        cam.kill()
        fcntl.flock(lock, fcntl.LOCK_UN)
        lock.close()


@pytest.fixture
def camera_config():
    """``camera_config(low, high="Fake_1", **gige)`` -> a validated camera section."""
    return make_camera_config


def make_camera_config(low: str, high: str = "Fake_1", *, bit_depth: int = 16, width: int = 64,
                       height: int = 48, exposures: tuple[float, float] = (0.002, 0.004), **gige) -> Camera:
    """A camera section driving ``low``/``high`` (the GigE fields in ``gige``)."""
    return Camera.model_validate({
        "sensors": [{"name": "low", "exposure_s": exposures[0]},
                    {"name": "high", "exposure_s": exposures[1]}],
        "width_px": width, "height_px": height, "bit_depth": bit_depth, "driver": "gige",
        "gige": {"low": low, "high": high, "timeout_ms": int(scaled_s(2.0) * 1000), **gige},
    })


# The fake devices serve a software trigger at the next tick of a 25 Hz grid, the GigE one a
# tick later now and then (its first frame after start too): two triggered fakes can be a
# 40 ms slot apart, and a loaded machine adds its scheduling delays (the test time factor
# scales this bound). Real imagers sharing a trigger are within the default 1 ms.
FAKE_SKEW_MS = 1000.0 * scaled_s(0.25)
