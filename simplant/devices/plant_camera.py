"""The simulated plant's double-CCD camera looking at the calibration target."""

from __future__ import annotations

import numpy as np

from controller.config import PlantConfig
from controller.devices.camera import DoubleCcdCamera, FramePair
from controller.geometry.vectors import unit
from simplant.devices.grids import camera_grid, coarse_grid
from simplant.devices.sensor import shot_law
from simplant.optics import MirrorSurface, render_spot

RENDER_RAYS = 80_000


class PlantClockCamera(DoubleCcdCamera):
    """A simulated double-CCD camera (``self.sim``, a :class:`simplant.devices.camera.SimulatedCamera`)
    of the plant (``self.plant``): a capture stops the plant clock while it is simulated and
    advances it by the HIGH exposure."""

    plant: object
    sim: object

    @property
    def exposures(self) -> tuple[float, float]:
        return self.sim.exposures

    def set_exposures(self, t_low: float, t_high: float) -> None:
        self.sim.set_exposures(t_low, t_high)

    def capture(self) -> FramePair:
        with self.plant.clock.frozen(advance_s=self.sim.exposures[1]):
            return self.sim.capture()


class PlantCamera(PlantClockCamera):
    """The plant's double-CCD camera (``plant``: a :class:`simplant.plant.SimulatedPlant`):
    :class:`simplant.devices.camera.SimulatedCamera` (two sensors with their own non-linear responses
    and gains) over :meth:`SimulatedPlant.scene`.

    The lamp brightness is set once so that a nominal spot of the first heliostat at the
    target centre peaks at 1.6x the HIGH sensor's full scale (HIGH saturates in the core,
    LOW does not), as in the error set. A capture stops the plant clock while it is simulated
    and advances it by the HIGH exposure. :meth:`inject_failure` makes the next captures
    raise :class:`CameraError` (fault tests).

    ``perspective`` (with ``camera.registration`` configured): each sensor sees the target
    through the true camera of :mod:`simplant.perspective` (pose error, lens distortion, the
    sensors misregistered), and :attr:`fiducials_lit` adds the target's lit fiducials.
    Otherwise both sensors see the target's rectified view (``camera_grid``).
    """

    def __init__(self, plant, cfg: PlantConfig, seed: int = 0, *, perspective: bool = False) -> None:
        from simplant.devices.camera import SimulatedCamera

        cam = cfg.camera
        self.plant = plant
        self.grid = camera_grid(cfg)
        self._scene_rng = np.random.default_rng([seed, 11])
        t_high = cam.sensors[1].exposure_s
        span = (1 << cam.bit_depth) - 1 - cam.dark_offset_counts
        self.counts_per_s = 1.6 * span / t_high / max(self._nominal_peak(), 1e-12)
        rows, cols = self.grid.shape
        yy, xx = np.mgrid[0:rows, 0:cols]
        # Stray light on the target: a dim pedestal (0.25 % of the nominal peak) with a gradient.
        self._ambient = (0.0025 + 0.0012 * xx / cols) * 1.6 * span / t_high
        # Gaussian shot noise where it is indistinguishable from Poisson behind the camera's read
        # noise: the sensors' Poisson draws were the plant's largest cost (simplant.devices.sensor).
        shot = shot_law(cam.read_noise_counts, cam.full_well_electrons, cam.bit_depth, cam.dark_offset_counts)
        self.sim = SimulatedCamera(cam, self._scene, seed=seed, clock=plant.clock, shot=shot)
        self.captures = 0
        self.fiducials_lit = False
        self.view = None
        if perspective and cam.registration is not None:
            from simplant.perspective import PerspectiveView, fiducial_scene, true_camera

            self.view = PerspectiveView(true_camera(cfg, seed), self.grid)
            # Fiducial lamps peaking at 80 % of HIGH's range at its starting exposure on the
            # target grid (the warp into the camera lowers the peak): bright, unclipped.
            self._fiducials = fiducial_scene(self.grid, np.asarray(cam.registration.fiducials_enu_m, float),
                                             0.8 * span / t_high)

    def _nominal_peak(self) -> float:
        p = self.plant
        hid = p.ids[0]
        hh = p.hidden[hid]
        lamp = np.asarray(p.lamp().position_enu_m, float)
        pos = hh.position
        n = unit(unit(lamp - pos) + unit(self.grid.center - pos))
        d = float(p.lamp().diameter_m) / float(np.linalg.norm(lamp - pos))
        nominal = MirrorSurface.from_config(p.cfg.heliostat(hid).mirror)
        coarse = coarse_grid(self.grid)
        return float(render_spot(pos, n, lamp, d, nominal, coarse, rng=np.random.default_rng(0),
                                 n_rays=RENDER_RAYS).max())

    def _scene(self) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        scene = self.plant.scene(self.grid, self._scene_rng) * self.counts_per_s + self._ambient
        if self.view is None:
            return scene
        return self.view.warp(scene + self._fiducials if self.fiducials_lit else scene)

    def true_crf(self):
        """The sensors' exact inverse responses (stand-in for an integrating-sphere CRF fit)."""
        return self.sim.true_crf()

    def inject_failure(self, count: int = 1) -> None:
        self.sim.inject_failure(count)

    def capture(self) -> FramePair:
        frame = super().capture()
        self.captures += 1
        return frame
