"""The simulated camera's view of the calibration target, and the coarser ray-tracing grid."""

from __future__ import annotations

from controller.config import PlantConfig
from controller.geometry.target_frame import TargetFrame
from simplant.optics import TargetGrid

RENDER_PITCH_M = 0.075  # ray-tracing grid pitch (then interpolated to the camera's)


def coarse_grid(grid: TargetGrid) -> TargetGrid:
    """The ray-tracing grid over the same area: pixels binned to about ``RENDER_PITCH_M``."""
    rows, cols = grid.shape
    k = max(1, int(RENDER_PITCH_M / max(grid.pixel_size_m)))
    return TargetGrid(grid.center, grid.normal, grid.u_axis, grid.v_axis, grid.width_m, grid.height_m,
                      (max(1, rows // k), max(1, cols // k)))


def camera_grid(cfg: PlantConfig) -> TargetGrid:
    """The camera's rectified view: square pixels, the whole target in view, centred."""
    cam = cfg.camera
    f = TargetFrame.from_config(cfg.target(), (cam.height_px, cam.width_px))
    return TargetGrid(f.center, f.normal, f.u, f.v, f.width_m, f.height_m, f.shape)
