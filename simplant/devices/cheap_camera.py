"""Cheap optics for large simulated fields: analytic beam spots instead of ray tracing.

:class:`BeamField` follows where every hidden heliostat's true beam goes (the reflection of
the lit lamp about the heliostat's true normal at its rods' true positions, as
:meth:`simplant.plant.SimulatedPlant.scene` finds it, with the canting shift of
:meth:`simplant.hidden.HiddenHeliostat.beam_normal`), recomputing a heliostat only when its rods moved.
:class:`CheapCamera` is a :class:`controller.devices.camera.DoubleCcdCamera` per target that
renders each beam landing in its view as an elliptical Gaussian (:func:`spot_covariance`) on
a small rectified grid (the config's ``camera.width_px`` × ``height_px``, e.g. 128 × 96),
through the simulated sensors of :class:`simplant.devices.camera.SimulatedCamera` (linear responses:
no CRF file needed; no fiducials, so no ``camera.registration``). The plant clock stands
still while a scene is drawn and advances by the HIGH exposure, as with the plant's camera.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Collection

import numpy as np

from controller.config import PlantConfig
from controller.geometry.vectors import unit
from simplant.devices.grids import camera_grid
from simplant.devices.plant_camera import PlantClockCamera

# The lamp's brightness: a reference spot (REF_SIGMA_M round, from a REF_AREA_M2 mirror facing
# the lamp) peaks at this fraction of the HIGH sensor's range. Every lamp gives the field the
# same irradiance (a far lamp is a stronger one).
PEAK_FRACTION = 0.7
REF_SIGMA_M = 0.3
REF_AREA_M2 = 8.0
# Stray light on the target, as a fraction of a spot's peak (the plant camera's pedestal).
AMBIENT_FRACTION = 0.0025
# A spot ends at this Mahalanobis radius (a finite mirror's spot has a compact footprint; a
# Gaussian's far tail would reach into the view from beams parked beside it).
SPOT_EXTENT_SIGMA = 3.0
# A beam that meets the target plane farther than this (nearly parallel to it) is not drawn.
MAX_THROW_M = 1000.0


def spot_covariance(distance_m, lamp_angle_rad, slope_error_rad, mirror_w_m, mirror_h_m, focal_m,
                    beam: np.ndarray, normal: np.ndarray, u_axis: np.ndarray,
                    v_axis: np.ndarray) -> np.ndarray:
    """2 × 2 covariance (m², target axes u, v) of a heliostat's spot on a target plane; every
    argument but the plane's axes may be an array over heliostats ((n,), beams (n, 3)): (n, 2, 2).

    Across the beam, per mirror axis, independent blurs add in quadrature:
    σ² = (αL/4)² + (2σ_s L)² + (w |1 − L/f|)² / 12 — the lamp disc of angular diameter α
    imaged at distance L (a uniform disc of radius r has σ = r/2), the slope error σ_s
    doubled on reflection, and the mirror of width w focused at f (a uniform band of width
    w|1 − L/f|). The mirror's width axis is taken along u, its height along v. An oblique
    beam (cos θ = |b·n|) stretches the footprint by 1/cos θ along the beam's in-plane direction d:
    Σ' = S Σ Sᵀ, S = I + (1/cos θ − 1) d dᵀ."""
    dist = np.asarray(distance_m, float)
    common = (np.asarray(lamp_angle_rad) * dist / 4.0) ** 2 + (2.0 * np.asarray(slope_error_rad) * dist) ** 2
    defocus = np.abs(1.0 - dist / np.asarray(focal_m, float))
    cov = np.zeros((*dist.shape, 2, 2))
    cov[..., 0, 0] = common + (np.asarray(mirror_w_m) * defocus) ** 2 / 12.0
    cov[..., 1, 1] = common + (np.asarray(mirror_h_m) * defocus) ** 2 / 12.0
    b = np.asarray(beam, float)
    cos_t = np.maximum(np.abs(b @ normal), 0.05)
    d = np.stack([b @ u_axis, b @ v_axis], axis=-1)
    norm = np.linalg.norm(d, axis=-1, keepdims=True)
    d = np.where(norm > 1e-9, d / np.maximum(norm, 1e-12), 0.0)
    stretch = np.eye(2) + (1.0 / cos_t - 1.0)[..., None, None] * d[..., :, None] * d[..., None, :]
    return stretch @ cov @ np.swapaxes(stretch, -1, -2)


def spot_peak(area_m2: float, cos_incidence: float, cov: np.ndarray) -> float:
    """Peak of a spot relative to the reference spot's (the constants above). Its power is the
    lamp irradiance on the mirror, ∝ A cos i, spread over the Gaussian of covariance Σ, whose
    peak is power / (2π √det Σ)."""
    power = area_m2 * max(cos_incidence, 0.0)
    return power / REF_AREA_M2 * REF_SIGMA_M ** 2 / float(np.sqrt(np.linalg.det(cov)))


class BeamField:
    """Every hidden heliostat's beam now (module docstring), shared by the targets' cameras.

    :meth:`beams` returns arrays over the heliostats: mirror centre (N, 3) m ENU, unit beam
    direction (N, 3), the lamp's distance (N,) m and the cosine of the lamp's incidence on the
    mirror (N,). A heliostat's beam is recomputed when the lamp or night changed or its rods
    moved; only heliostats sent a command since they last stood still are looked at
    (:meth:`touch`, called by the in-process drives), so a capture over a field of thousands
    costs what its moving heliostats cost."""

    def __init__(self, plant) -> None:
        self.plant = plant
        self.ids = list(plant.hidden)
        n = len(self.ids)
        self.pos = np.zeros((n, 3))
        self.dir = np.zeros((n, 3))
        self.lamp_m = np.ones(n)
        self.cos_i = np.zeros(n)
        self._key: list[tuple | None] = [None] * n
        self._scene: tuple | None = None  # (night, lamp) the beams were computed under
        self._active: set[int] = set()
        self._index = {hid: i for i, hid in enumerate(self.ids)}
        self._lock = threading.Lock()

    def touch(self, hid: str) -> None:
        """``hid`` was sent a command: its rods may move until it stands still again."""
        with self._lock:
            self._active.add(self._index[hid])

    def beams(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        p = self.plant
        lamp_cfg = p.lamp()
        lamp = np.asarray(lamp_cfg.position_enu_m, float)
        with self._lock:
            scene = (p.night, p.lit)
            look = range(len(self.ids)) if scene != self._scene else sorted(self._active)
            self._scene = scene
            for i in look:
                hh = p.hidden[self.ids[i]]
                steps = hh.controller.output_steps()
                if not hh.controller.status()["moving"]:
                    self._active.discard(i)
                key = (steps, p.night, p.lit)
                if key == self._key[i]:
                    continue  # rods, night and lamp unchanged: so is the beam
                n = hh.beam_normal(p.true_normal(self.ids[i]))
                pos = hh.truth.mirror_center(*steps, night=p.night)
                s = unit(lamp - pos)
                self.pos[i] = pos
                self.dir[i] = 2.0 * (s @ n) * n - s
                self.lamp_m[i] = float(np.linalg.norm(lamp - pos))
                self.cos_i[i] = float(s @ n)
                self._key[i] = key
            return self.pos.copy(), self.dir.copy(), self.lamp_m.copy(), self.cos_i.copy()


class CheapCamera(PlantClockCamera):
    """The double-CCD camera of one target over :class:`BeamField` (module docstring).
    ``beams_in_view`` lists, per capture, the heliostats whose beam was drawn (the truth of
    "one beam per target")."""

    def __init__(self, plant, field: BeamField, cfg: PlantConfig, seed: int = 0) -> None:
        from simplant.devices.camera import SimulatedCamera

        cam = cfg.camera
        self.plant = plant
        self.field = field
        self.cfg = cfg
        self.grid = camera_grid(cfg)
        span = (1 << cam.bit_depth) - 1 - cam.dark_offset_counts
        self.peak = PEAK_FRACTION * span / cam.sensors[1].exposure_s  # counts/s
        rows, cols = self.grid.shape
        self._yy, self._xx = np.mgrid[0:rows, 0:cols].astype(float)
        self.sim = SimulatedCamera(cam, self._scene, seed=seed, clock=plant.clock, knees=(0.0, 0.0))
        mirrors = [cfg.heliostat(hid).mirror for hid in field.ids]
        self.slope = np.array([1e-3 * m.slope_error_mrad for m in mirrors])
        self.width = np.array([m.width_m for m in mirrors])
        self.height = np.array([m.height_m for m in mirrors])
        self.focal = np.array([m.focal_length_m for m in mirrors])
        self.beams_in_view: list[tuple[str, ...]] = []
        self.hits: list[dict[str, tuple[float, float, float]]] = []  # per capture: hid -> true ENU hit
        # Who is meant to be on this target now (set by whoever watches the controller, e.g. a
        # benchmark's observer): each capture then records in ``strays`` the beams in view that
        # are not (several beams per target: a beam that is not the capture's).
        self.expected: Callable[[], Collection[str]] | None = None
        self.strays: list[tuple[str, ...]] = []
        # Told of every capture with a stray: its strays and every drawn beam's true hit (ENU m),
        # so that the watcher can say where each stray was and what its cycle was doing.
        self.stray_seen: Callable[[tuple[str, ...], dict[str, tuple]], None] | None = None

    def _scene(self) -> np.ndarray:
        g = self.grid
        img = np.full(g.shape, AMBIENT_FRACTION * self.peak)
        if self.plant.lamp() is None:  # every lamp dark (a lamp change): no beam
            self.beams_in_view.append(())
            self.hits.append({})
            if self.expected is not None:
                self.strays.append(())
            return img
        pos, beam, lamp_m, cos_i = self.field.beams()
        lamp_d = float(self.plant.lamp().diameter_m)
        denom = beam @ g.normal
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((g.center - pos) @ g.normal) / denom
        ok = np.flatnonzero(np.isfinite(t) & (t > 0) & (t < MAX_THROW_M))
        hit = pos[ok] + t[ok, None] * beam[ok]
        du, dv = g.pixel_size_m
        # Every beam's spot at once; only those whose footprint reaches the view are drawn.
        covs = spot_covariance(t[ok], lamp_d / lamp_m[ok], self.slope[ok], self.width[ok], self.height[ok],
                               self.focal[ok], beam[ok], g.normal, g.u_axis, g.v_axis)
        xs, ys = g.enu_to_pixel(hit)
        sx, sy = np.sqrt(covs[:, 0, 0]) / du, np.sqrt(covs[:, 1, 1]) / dv
        rows, cols = g.shape
        near = ((-SPOT_EXTENT_SIGMA * sx < xs + 0.5) & (xs + 0.5 < cols + SPOT_EXTENT_SIGMA * sx)
                & (-SPOT_EXTENT_SIGMA * sy < ys + 0.5) & (ys + 0.5 < rows + SPOT_EXTENT_SIGMA * sy))
        # The plant's identity faults (SpotTruth.swap / stray): a spot drawn where another's was.
        shifts = self.plant.spot_truth.shifts({self.field.ids[ok[k]]: hit[k] - g.center
                                               for k in np.flatnonzero(near)})
        for k in np.flatnonzero(near):
            shift = shifts.get(self.field.ids[ok[k]])
            if shift is not None:
                hit[k] = hit[k] + shift
                xs[k], ys[k] = g.enu_to_pixel(hit[k])
        seen, hits = [], {}
        for k in np.flatnonzero(near):
            i = ok[k]
            hid = self.field.ids[i]
            cov, x, y = covs[k], float(xs[k]), float(ys[k])
            # Elliptical Gaussian in pixels: exp(-½ rᵀ C⁻¹ r), C the covariance in px².
            c = cov / np.array([[du * du, du * dv], [du * dv, dv * dv]])
            ci = np.linalg.inv(c)
            rx, ry = self._xx - x, self._yy - y
            m2 = ci[0, 0] * rx * rx + 2 * ci[0, 1] * rx * ry + ci[1, 1] * ry * ry
            if not (m2 <= SPOT_EXTENT_SIGMA ** 2).any():
                continue
            peak = self.peak * spot_peak(self.width[i] * self.height[i], float(cos_i[i]), cov)
            img += peak * np.where(m2 <= SPOT_EXTENT_SIGMA ** 2, np.exp(-0.5 * m2), 0.0)
            seen.append(hid)
            hits[hid] = tuple(float(v) for v in hit[k])
        self.beams_in_view.append(tuple(seen))
        self.hits.append(hits)
        self.plant.spot_truth.record(hits)
        if self.expected is not None:
            meant = self.expected()
            stray = tuple(h for h in seen if h not in meant)
            self.strays.append(stray)
            if stray and self.stray_seen is not None:
                self.stray_seen(stray, hits)
        return img
