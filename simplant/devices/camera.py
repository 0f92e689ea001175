"""Simulated double-CCD camera: two sensor models looking at one irradiance scene.

The scene is whatever ``scene_fn()`` returns at capture time: an irradiance image of what the
camera sees (or a (LOW, HIGH) pair of them when the two sensors see it differently, see
:mod:`simplant.perspective`), in **counts per second at unit gain before response** (see
:mod:`simplant.devices.sensor`), shape (rows, cols). The simulated plant plugs beam spots from
:func:`simplant.optics.render_spot` in here, scaled by ``irradiance_scale``.

Both sensors expose the *same* scene at the same instant (prism camera) with their own
exposure time, gain (a small mismatch from the config, e.g. 1.03) and non-linear response
(:func:`simplant.devices.sensor.knee_response`, a different knee per sensor). Their true
inverse responses are available as a :class:`controller.imaging.crf.Crf` (``true_crf()``),
the stand-in for an integrating-sphere calibration.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from controller.devices.camera import CameraError, DoubleCcdCamera, FramePair
from controller.imaging.crf import Crf
from simplant.devices.sensor import SensorModel, knee_response

# Knee of each sensor's response: a mild compression (slope 1.15 / 1.25 at black) that a
# linear CRF would miss by a few per cent, as the fitted CRFs of real CCDs do.
DEFAULT_KNEES = (0.15, 0.25)


class SimulatedCamera(DoubleCcdCamera):
    """Double-CCD camera over a scene function.

    Parameters
    ----------
    config_camera : :class:`controller.config.Camera` (sensors, exposures, gains, bit depth,
        dark offset, read noise, full well).
    scene_fn : ``() -> ndarray`` irradiance image (counts/s at unit gain), called per capture.
    rng : numpy Generator for the noise; else ``seed`` makes one.
    clock : timestamp source in seconds (default ``time.monotonic``), injectable.
    irradiance_scale : multiplies the scene (e.g. counts/s per W/m² of ``render_spot``).
    knees : response knees of the two sensors (0 = linear).
    shot : shot-noise law of both sensors, ``"poisson"`` or its faster normal approximation
        ``"gauss"`` (:mod:`simplant.devices.sensor`).
    """

    def __init__(self, config_camera, scene_fn: Callable[[], np.ndarray],
                 rng: np.random.Generator | None = None, seed: int = 0, *,
                 clock: Callable[[], float] = time.monotonic,
                 irradiance_scale: float = 1.0, knees: tuple[float, float] = DEFAULT_KNEES,
                 shot: str = "poisson") -> None:
        cam = config_camera
        self.sensors = tuple(
            SensorModel(bit_depth=cam.bit_depth, dark_offset=cam.dark_offset_counts,
                        read_noise=cam.read_noise_counts, full_well=cam.full_well_electrons,
                        gain=s.gain, response=knee_response(k), shot=shot)
            for s, k in zip(cam.sensors, knees, strict=True))
        self.names = tuple(s.name for s in cam.sensors)
        self._scene_fn = scene_fn
        self._rng = rng if rng is not None else np.random.default_rng(seed)
        self._clock = clock
        self._scale = float(irradiance_scale)
        self._exposures = (cam.sensors[0].exposure_s, cam.sensors[1].exposure_s)
        self._failures = 0
        self.frames_captured = 0

    @property
    def exposures(self) -> tuple[float, float]:
        return self._exposures

    def set_exposures(self, t_low: float, t_high: float) -> None:
        if not (0 < t_low <= t_high <= 10):
            raise CameraError(f"exposures must satisfy 0 < LOW <= HIGH <= 10 s, got ({t_low}, {t_high})")
        self._exposures = (float(t_low), float(t_high))

    def inject_failure(self, count: int = 1) -> None:
        """Make the next ``count`` captures raise CameraError (fault tests)."""
        self._failures += int(count)

    def true_crf(self) -> Crf:
        """The sensors' exact inverse responses, LOW first."""
        return Crf.from_tables([s.inverse_response() for s in self.sensors], self.names)

    def capture(self) -> FramePair:
        if self._failures > 0:
            self._failures -= 1
            raise CameraError("simulated camera failure (injected)")
        raw = self._scene_fn()
        scenes = [np.asarray(x, dtype=float) for x in (raw if isinstance(raw, tuple) else (raw, raw))]
        for scene in scenes:
            if scene.ndim != 2:
                raise CameraError(f"scene must be a 2-D irradiance image, got shape {scene.shape}")
            if not np.all(np.isfinite(scene)):
                raise CameraError("scene contains NaN or infinite irradiance")
        stamp = float(self._clock())
        low = self.sensors[0].expose(scenes[0] * self._scale, self._exposures[0], self._rng)
        high = self.sensors[1].expose(scenes[1] * self._scale, self._exposures[1], self._rng)
        self.frames_captured += 1
        return FramePair(low, high, self._exposures, stamp,
                         {"camera": "simulated", "sensors": list(self.names), "frame": self.frames_captured})
