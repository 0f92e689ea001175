"""The simulated truth of one heliostat: its hidden kinematics, error case, mirror and firmware
controller, and the repeatability error of each rest pose (what the controller must find out)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from controller.geometry.vectors import unit
from simplant.errorset import ErrorCase
from simplant.firmware.physics import SimController
from simplant.optics import MirrorSurface, mirror_frame
from simplant.truth import HeliostatTruth


@dataclass
class HiddenHeliostat:
    """The simulated truth of one heliostat (what the controller must find out)."""

    heliostat_id: str
    truth: HeliostatTruth
    case: ErrorCase
    mirror: MirrorSurface
    controller: SimController
    noise_key: tuple[int, ...]  # (seed, stream, heliostat index): seeds the repeatability draws
    _settled: tuple = ((), (0.0, 0.0))  # the last (night, pose) key and its draw
    pose_cache: tuple | None = None  # (steps, jitter, night), normal, mirror centre (simplant.poses)

    @property
    def position(self) -> np.ndarray:
        return self.truth.position

    def beam_normal(self, n: np.ndarray) -> np.ndarray:
        """The normal whose specular reflection carries the beam's energy centroid: the central
        normal ``n`` tilted by the mirror's area-mean extra slope (non-zero for a canted facet;
        zero for symmetric shapes: sag, twist, split, focus)."""
        mx, my = self.mean_slope
        if mx == 0.0 and my == 0.0:
            return n
        e_w, e_h = mirror_frame(n)
        return unit(n - mx * e_w - my * e_h)

    @cached_property
    def mean_slope(self) -> tuple[float, float]:
        """:func:`mean_slope` of the (fixed) mirror, computed once."""
        return mean_slope(self.mirror)

    def settle(self, steps: tuple[float, float], night: int) -> tuple[float, float]:
        """The repeatability error (rad, elevation and azimuth) of the rods at ``steps`` on
        ``night``: a draw per pose, seeded by (seed, heliostat, night, pose). Drawing from a
        shared stream whenever someone looked at a moved heliostat made the draws depend on
        how often the safety monitor and the cameras sampled it during the slews (wall-clock
        timing), so one seed gave different figures run to run."""
        # Millisteps: the float noise of the motion integration does not make a new pose.
        key = (night, *(int(round(v * 1000.0)) % (1 << 32) for v in steps))
        if key != self._settled[0]:
            rng = np.random.default_rng([*self.noise_key, *key])
            self._settled = (key, tuple(rng.normal(0.0, self.truth.repeatability, 2)))
        return self._settled[1]


def mean_slope(mirror: MirrorSurface, samples: int = 64) -> tuple[float, float]:
    """Area mean of the mirror's extra slope field (rad along its width and height axes)."""
    if mirror.deformation is None:
        return 0.0, 0.0
    x, y = np.meshgrid((np.arange(samples) + 0.5) / samples * mirror.width_m - mirror.width_m / 2,
                       (np.arange(samples) + 0.5) / samples * mirror.height_m - mirror.height_m / 2)
    dx, dy = mirror.deformation(x, y)
    return float(np.mean(dx)), float(np.mean(dy))
