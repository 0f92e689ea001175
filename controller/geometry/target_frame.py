"""A planar target as a rectified camera sees it: a pixel grid laid over the target plane."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controller.geometry.vectors import unit

_UP = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class TargetFrame:
    """Rectified camera view of a planar target (pixel grid over the target plane).

    Image x (column) runs along ``u = unit(up × normal)`` (for a north-facing target that is
    west, i.e. image left = east, as in the PAINT images), image y (row) along ``v = u × normal``
    (down). Pixel (0, 0) is the centre of the top-left pixel, half a pixel inside the corner
    ``center - W/2 u - H/2 v``. Pixels are square (Hu moments are not invariant to an
    anisotropic scale): the pitch is the larger of target width/cols and height/rows, so the
    view ``W x H`` covers the whole target and is centred on it.
    """

    center: np.ndarray
    normal: np.ndarray
    u: np.ndarray
    v: np.ndarray
    width_m: float
    height_m: float
    shape: tuple[int, int]

    @classmethod
    def from_config(cls, target, shape: tuple[int, int]) -> TargetFrame:
        n = unit(np.asarray(target.normal, float))
        u = np.cross(_UP, n)
        if np.linalg.norm(u) < 1e-9:
            u = np.array([1.0, 0.0, 0.0]) - n[0] * n
        u = unit(u)
        rows, cols = int(shape[0]), int(shape[1])
        pitch = max(float(target.width_m) / cols, float(target.height_m) / rows)
        return cls(np.asarray(target.center_enu_m, float), n, u, np.cross(u, n), cols * pitch, rows * pitch,
                   (rows, cols))

    def pixel_to_enu(self, x_px: float, y_px: float) -> np.ndarray:
        """ENU point (3,) on the target plane for pixel coordinates (x = column, y = row)."""
        du, dv = self.width_m / self.shape[1], self.height_m / self.shape[0]
        return (self.center + ((x_px + 0.5) * du - self.width_m / 2) * self.u
                + ((y_px + 0.5) * dv - self.height_m / 2) * self.v)

    def side(self, heliostat_pos: np.ndarray) -> np.ndarray:
        """Unit in-plane direction beside the target on the heliostat's own side (±u)."""
        return self.u if float((np.asarray(heliostat_pos) - self.center) @ self.u) >= 0 else -self.u
