"""The simulated camera's true perspective view of the target (the simulator's truth).

The controller is told a nominal camera (``camera.position_enu_m`` looking at the target
centre, ``camera.registration``'s focal length and lens distortion). The real one differs:

* its pose is off by a few mrad (rotation, ``POSE_ERROR_MRAD`` σ per axis) and a few cm
  (position, ``POSE_ERROR_M`` σ per axis), drawn once per seed;
* its two sensors are not aligned: HIGH's image is LOW's shifted by ``HIGH_SHIFT_PX`` and
  rotated by ``HIGH_ROTATION_MRAD`` about the image centre (prism assembly tolerance).

The intrinsics (focal length, principal point, distortion) are the configured ones: a lab
calibration knows them. The scene is still rendered on the target-plane grid
(:func:`simplant.devices.grids.camera_grid`); :class:`PerspectiveView` warps it into each sensor's image
through the true model (camera pixel → ray → target plane → grid pixel, one ``cv2.remap``
with tables built once). Only this module knows the truth; the controller never reads it.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from controller.config import PlantConfig
from controller.imaging.registration import CameraModel
from simplant.optics import TargetGrid

POSE_ERROR_MRAD = 2.0
POSE_ERROR_M = 0.03
HIGH_SHIFT_PX = (0.3, -0.1)
HIGH_ROTATION_MRAD = 0.5
FIDUCIAL_SIGMA_M = 0.02  # a lit marker ~5 cm across: a blob of σ ≈ 2 px at 100 m


@dataclass(frozen=True, eq=False)  # numpy fields
class TrueCamera:
    """LOW's true model and HIGH's offset from it in the image: p_high = Rθ (p_low − c) + c + s,
    c the image centre, θ ``high_rotation_rad``, s ``high_shift_px``."""

    low: CameraModel
    high_shift_px: np.ndarray
    high_rotation_rad: float

    def _centre(self) -> np.ndarray:
        w, h = self.low.image_size
        return np.array([(w - 1) / 2, (h - 1) / 2])

    def _rot(self, sign: float) -> np.ndarray:
        c, s = np.cos(sign * self.high_rotation_rad), np.sin(sign * self.high_rotation_rad)
        return np.array([[c, -s], [s, c]])

    def project(self, points_enu: np.ndarray, sensor: int) -> np.ndarray:
        """True pixel (u, v) of ENU points (N, 3) in sensor 0 (LOW) or 1 (HIGH)."""
        p = self.low.project(points_enu)
        if sensor == 0:
            return p
        c = self._centre()
        return (p - c) @ self._rot(1.0).T + c + self.high_shift_px

    def to_low(self, px: np.ndarray, sensor: int) -> np.ndarray:
        """LOW pixel seeing what ``px`` (N, 2) of ``sensor`` sees."""
        if sensor == 0:
            return px
        c = self._centre()
        return (px - c - self.high_shift_px) @ self._rot(-1.0).T + c


def _look_at(c: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Rotation (rows = camera x right, y down, z forward in ENU) of a level camera at c looking
    at ``target``."""
    z = (target - c) / np.linalg.norm(target - c)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    return np.vstack([x, np.cross(z, x), z])


def true_camera(cfg: PlantConfig, seed: int) -> TrueCamera:
    """The plant's real camera for ``cfg`` (``camera.registration`` set): the nominal one with
    a pose error drawn from ``seed``."""
    cam = cfg.camera
    reg = cam.registration
    w, h = cam.width_px, cam.height_px
    cx, cy = reg.principal_point_px if reg.principal_point_px is not None else ((w - 1) / 2, (h - 1) / 2)
    k = np.array([[reg.focal_px, 0.0, cx], [0.0, reg.focal_px, cy], [0.0, 0.0, 1.0]])
    look = np.asarray(cfg.target().center_enu_m if reg.look_at_enu_m is None else reg.look_at_enu_m, float)
    nominal_c = np.asarray(cam.position_enu_m, float)
    r = _look_at(nominal_c, look)
    roll = reg.roll_mrad * 1e-3
    r = np.array([[np.cos(roll), np.sin(roll), 0], [-np.sin(roll), np.cos(roll), 0], [0, 0, 1]]) @ r
    rng = np.random.default_rng([seed, 17])
    r = cv2.Rodrigues(rng.normal(0.0, POSE_ERROR_MRAD * 1e-3, 3))[0] @ r
    c = nominal_c + rng.normal(0.0, POSE_ERROR_M, 3)
    k1, k2, p1, p2 = reg.distortion
    model = CameraModel(k, np.array([k1, k2, p1, p2, 0.0]), cv2.Rodrigues(r)[0].reshape(3), -r @ c, (w, h))
    return TrueCamera(model, np.asarray(HIGH_SHIFT_PX, float), HIGH_ROTATION_MRAD * 1e-3)


LATTICE_PX = 8  # the warp tables are traced exactly every 8 camera pixels, bilinear between


class PerspectiveView:
    """Warps target-grid scenes into the two sensors' images through a :class:`TrueCamera`.

    The tables (camera pixel → grid pixel) are traced exactly through the true model on a
    lattice of every ``LATTICE_PX``-th camera pixel (and the last row and column) and
    interpolated bilinearly in between: the map is smooth (a plane seen in perspective through
    mild distortion), the interpolation error stays below 0.005 grid px on the demo cameras
    (``tests/test_simplant_speed.py`` compares it with every pixel traced), and tracing all
    million pixels, each undistorted iteratively, took a second per camera at every start."""

    def __init__(self, truth: TrueCamera, grid: TargetGrid) -> None:
        self.truth = truth
        self.grid = grid
        self.maps = [tuple(m.astype(np.float32) for m in self.grid_coords(sensor, LATTICE_PX))
                     for sensor in (0, 1)]

    def grid_coords(self, sensor: int, step: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """(x, y) grid pixel (float64, shape (h, w); −1e6 where the ray misses the plane) that
        each pixel of ``sensor`` sees, traced every ``step`` pixels and bilinear in between
        (``step`` 1: every pixel traced)."""
        w, h = self.truth.low.image_size
        us = np.unique(np.r_[np.arange(0, w, step), w - 1]).astype(float)
        vs = np.unique(np.r_[np.arange(0, h, step), h - 1]).astype(float)
        uu, vv = np.meshgrid(us, vs)
        px = np.column_stack([uu.ravel(), vv.ravel()])
        g = self.grid
        enu = self.truth.low.pixel_to_target(self.truth.to_low(px, sensor), g.center, g.normal)
        rel = enu - g.center
        du, dv = g.width_m / g.shape[1], g.height_m / g.shape[0]
        # Grid pixel (x, y) has its centre at ((x + 0.5) du − W/2) u + ((y + 0.5) dv − H/2) v.
        gx = ((rel @ g.u_axis + g.width_m / 2) / du - 0.5).reshape(len(vs), len(us))
        gy = ((rel @ g.v_axis + g.height_m / 2) / dv - 0.5).reshape(len(vs), len(us))
        if step == 1:
            return np.nan_to_num(gx, nan=-1e6), np.nan_to_num(gy, nan=-1e6)
        if not (np.isfinite(gx).all() and np.isfinite(gy).all()):
            return self.grid_coords(sensor, 1)  # a ray misses the plane: no interpolating across
        x, y = np.arange(w, dtype=float), np.arange(h, dtype=float)
        i = np.clip(np.searchsorted(us, x, side="right") - 1, 0, len(us) - 2)
        j = np.clip(np.searchsorted(vs, y, side="right") - 1, 0, len(vs) - 2)
        tx = (x - us[i]) / (us[i + 1] - us[i])
        ty = ((y - vs[j]) / (vs[j + 1] - vs[j]))[:, None]

        def bilinear(t: np.ndarray) -> np.ndarray:
            top, bottom = t[j], t[j + 1]
            return ((top[:, i] * (1 - tx) + top[:, i + 1] * tx) * (1 - ty)
                    + (bottom[:, i] * (1 - tx) + bottom[:, i + 1] * tx) * ty)

        return bilinear(gx), bilinear(gy)

    def warp(self, scene: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(LOW, HIGH) irradiance images of a grid scene (bilinear; 0 off the target grid)."""
        img = np.asarray(scene, np.float32)
        return tuple(cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
                     .astype(float) for mx, my in self.maps)


def fiducial_scene(grid: TargetGrid, points_enu: np.ndarray, peak: float) -> np.ndarray:
    """Lit fiducials on ``grid``: a Gaussian blob of σ ``FIDUCIAL_SIGMA_M`` and height ``peak``
    centred on each ENU point (projected onto the grid plane)."""
    rows, cols = grid.shape
    du, dv = grid.width_m / cols, grid.height_m / rows
    img = np.zeros((rows, cols))
    for p in np.asarray(points_enu, float).reshape(-1, 3):
        rel = p - grid.center
        x = (rel @ grid.u_axis + grid.width_m / 2) / du - 0.5
        y = (rel @ grid.v_axis + grid.height_m / 2) / dv - 0.5
        sx, sy = FIDUCIAL_SIGMA_M / du, FIDUCIAL_SIGMA_M / dv
        x0, x1 = max(int(x - 6 * sx), 0), min(int(x + 6 * sx) + 2, cols)
        y0, y1 = max(int(y - 6 * sy), 0), min(int(y + 6 * sy) + 2, rows)
        if x1 <= x0 or y1 <= y0:
            continue
        yy, xx = np.mgrid[y0:y1, x0:x1]
        img[y0:y1, x0:x1] += peak * np.exp(-0.5 * (((xx - x) / sx) ** 2 + ((yy - y) / sy) ** 2))
    return img
