"""The simulated plant's cameras as GigE Vision devices: per target, the double-CCD camera's
LOW and HIGH imagers (:class:`simplant.devices.gige_imager.GigeImagerServer`), each on a loopback
address of its own (127.0.0.2 and up, the first free), their frames rendered by the target's
:class:`simplant.devices.plant_camera.PlantCamera` — so the beams are where the plant's drives point
them.

A prism camera exposes both sensors at once: the first imager triggered renders a pair with
both imagers' exposures and keeps the other's frame for that imager's trigger (both frames carry
the render's timestamp, so the controller sees no skew). A kept frame older than
:data:`KEEP_S` is dropped and rendered again: it would show a past scene.
"""

from __future__ import annotations

import errno
import threading
import time

import numpy as np

from simplant.devices.gige_imager import GigeImagerServer

FIRST_ADDRESS, LAST_ADDRESS = 2, 254  # 127.0.0.N; 127.0.0.1 stays free for other GigE devices
KEEP_S = 5.0
ROLES = ("LOW", "HIGH")


class GigeCamera:
    """The two imagers of ``camera`` (a :class:`simplant.devices.plant_camera.PlantCamera`); ``name``
    goes into their serials."""

    def __init__(self, camera, name: str) -> None:
        self.camera = camera
        self.name = name
        self.imagers: list[GigeImagerServer] = []
        self._lock = threading.Lock()
        self._kept: list[tuple[np.ndarray, int, float] | None] = [None, None]

    def start(self) -> tuple[str, str]:
        """Serve both imagers; their (LOW, HIGH) addresses."""
        for role in range(2):
            serial = f"{self.name}-{ROLES[role]}"[:15]
            self.imagers.append(serve_imager(serial, lambda r=role: self._frame(r)))
        return self.imagers[0].address, self.imagers[1].address

    def stop(self) -> None:
        for imager in self.imagers:
            imager.stop()
        self.imagers.clear()

    def _frame(self, role: int) -> tuple[np.ndarray, int]:
        with self._lock:
            kept, self._kept[role] = self._kept[role], None
            if kept is not None and time.monotonic() - kept[2] < KEEP_S:
                return kept[0], kept[1]
            self.camera.set_exposures(*(imager.exposure_s() for imager in self.imagers))
            pair = self.camera.capture()
            stamp = time.time_ns()
            frames = (pair.low, pair.high)
            self._kept[1 - role] = (frames[1 - role], stamp, time.monotonic())
            return frames[role], stamp


def serve_imager(serial: str, frame) -> GigeImagerServer:
    """An imager started on the first free loopback address (OSError when none is)."""
    for n in range(FIRST_ADDRESS, LAST_ADDRESS + 1):
        server = GigeImagerServer(f"127.0.0.{n}", serial, frame)
        try:
            server.start()
        except OSError as exc:
            if exc.errno != errno.EADDRINUSE:
                raise
            continue
        return server
    raise OSError(errno.EADDRINUSE, f"no free loopback address 127.0.0.{FIRST_ADDRESS}-{LAST_ADDRESS} "
                                    "for a GigE Vision imager (port 3956)")
