"""Deterministic error cases rendered by the simulated plant: the recognition test set.

For one heliostat of the plant config (default: the demo field's H09 under the lamp) every
error case is a fixed heliostat state. It has a *pointing* part (tracking-error parameters of
:mod:`controller.geometry.error_model`, e.g. encoder offsets, pedestal tilt) and, for most
cases, a *shape* part (surface slope field or motion during the exposure). Hu moments are
invariant to translation, so only the shape part makes a case recognisable; the pointing part
is what the library entry's coarse ``correction`` undoes.

Cases (``--cases N`` takes the first N):

=================  ==========================================================================
tracking-offset    Δα = +3, Δε = -2 mrad encoder offsets and a 2 mrad pedestal tilt east.
                   Pure pointing: nominal focused spot, displaced.
wind-load          torsion of the frame about its vertical axis, dz/dx = k·y with k = 6 mrad/m,
                   plus 1 mrad elevation deflection: a sheared spot.
gear-backlash      a badly worn azimuth gear (60 mrad dead band): gusts sweep the mirror across
                   the band during the exposure, so the spot is smeared along the azimuth
                   direction to about twice its width.
canting-error      the upper-right facet quadrant tilted by (+3, +3) mrad: an off-axis lobe.
defocus            mirror curvature 1.6x too strong (focal length 0.62 x slant range): the
                   beam crosses over before the target and arrives larger and ring-like.
gravity-sag        cylindrical sag about the horizontal axis, dz/dy = y / 40 m^-1 extra:
                   astigmatic, vertically stretched spot.
facet-split        left and right halves canted apart by ±2.5 mrad: a double spot.
=================  ==========================================================================

Each view: the lamp-lit spot is ray traced onto a target-plane pixel grid
(:func:`simplant.optics.render_spot`), exposed as a double-CCD pair by
:class:`simplant.devices.sensor.SensorModel` and merged by :class:`controller.imaging.hdr.HdrMerger`
into a float HDR image. Library views use the nominal framing; test views are perturbed
deterministically from the seed by translation (grid centre ±0.3 m), scaling (pixel pitch
x 0.8-1.25), rotation (grid axes turned about the target normal by 0-360°), exposure change
(x 0.6-1.5) and fresh sensor and ray-sampling noise.

Combined errors (``combined=True``, ``heliocal sim errorset --combined``): every pair of the chosen
cases that both change the spot's shape, as a case of its own labelled ``"a+b"``
(:meth:`ErrorCase.combined`, :func:`shape_pairs`).

Those nuisances are what Hu moments ignore by construction. To measure generalisation the set
can span what they do not ignore: several heliostats and light sources (:func:`scene_from_config`
per heliostat/source) and error sizes (:meth:`ErrorCase.scaled`: the same mechanism at m times
its size), for the library and, held out, for the test views (:func:`write_errorset`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields, replace
from functools import partial
from pathlib import Path

import numpy as np

from controller.config import Camera, PlantConfig
from controller.geometry.error_model import TrackingErrorParams, actual_normal_from_angles
from controller.geometry.kinematics import HeliostatKinematics, angles_from_normal
from controller.geometry.vectors import unit, vector_to_azel
from controller.imaging.hdr import HdrMerger
from controller.io.images import write_float_image, write_preview
from controller.recognition.library_io import write_manifest
from simplant.devices.sensor import SensorModel
from simplant.optics import MirrorSurface, TargetGrid, render_spot

Deformation = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]

GRID_PX = 160
GRID_M = 9.0
N_RAYS = 150_000


@dataclass(frozen=True)
class ErrorCase:
    """One deterministic error state. Angles in rad; ``deformation`` adds mirror slopes (rad)
    at mirror coordinates (m); ``rock_az_rad`` is the azimuth dead band swept during exposure;
    ``focus_factor`` multiplies the mirror's curvature."""

    label: str
    params: TrackingErrorParams = field(default_factory=TrackingErrorParams)
    deformation: Deformation | None = None
    rock_az_rad: float = 0.0
    focus_factor: float = 1.0
    magnitude: float = 1.0

    def scaled(self, m: float) -> ErrorCase:
        """The same mechanism at ``m`` times this size: every tracking-error parameter, the
        slope field, the dead band and the curvature excess (``focus_factor - 1``) times ``m``."""
        if not m > 0:
            raise ValueError(f"magnitude must be positive, got {m}")
        params = TrackingErrorParams(**{f.name: m * getattr(self.params, f.name)
                                        for f in fields(self.params)})
        deformation = None if self.deformation is None else partial(_scaled_slopes, self.deformation, m)
        return replace(self, params=params, deformation=deformation, rock_az_rad=m * self.rock_az_rad,
                       focus_factor=1.0 + m * (self.focus_factor - 1.0), magnitude=m * self.magnitude)

    def combined(self, other: ErrorCase) -> ErrorCase:
        """Both mechanisms at once, label ``"a+b"``: tracking-error parameters, slope fields and
        dead bands add, curvature excesses add; each at its own size (magnitude 1), so that
        :meth:`scaled` scales the pair together."""
        params = TrackingErrorParams(**{f.name: getattr(self.params, f.name) + getattr(other.params, f.name)
                                        for f in fields(self.params)})
        parts = tuple(d for d in (self.deformation, other.deformation) if d is not None)
        deformation = None if not parts else parts[0] if len(parts) == 1 else partial(_summed_slopes, parts)
        return ErrorCase(f"{self.label}+{other.label}", params, deformation,
                         rock_az_rad=self.rock_az_rad + other.rock_az_rad,
                         focus_factor=1.0 + (self.focus_factor - 1.0) + (other.focus_factor - 1.0))

    def has_shape(self) -> bool:
        """Whether the case changes the spot's shape (slopes, motion or focus), not only where it lands."""
        return self.deformation is not None or self.rock_az_rad != 0.0 or self.focus_factor != 1.0

    def error_params(self) -> dict[str, float]:
        """What a library entry records about this state: magnitude and pointing parameters (mrad)."""
        return {"magnitude": self.magnitude} | {k: v for k, v in self.params.to_dict().items() if v != 0.0}


def _scaled_slopes(deformation: Deformation, m: float, x: np.ndarray, y: np.ndarray):
    sx, sy = deformation(x, y)
    return m * sx, m * sy


def _summed_slopes(parts: tuple[Deformation, ...], x: np.ndarray, y: np.ndarray):
    slopes = [d(x, y) for d in parts]
    return sum(sx for sx, _ in slopes), sum(sy for _, sy in slopes)


def shape_pairs(cases: Sequence[ErrorCase]) -> list[ErrorCase]:
    """Every pair of ``cases`` that both change the spot's shape, combined (:meth:`ErrorCase.combined`).

    A pure pointing case (tracking-offset) is left out: Hu moments ignore translation, so
    "tracking-offset + X" *is* X to them, a label no shape could earn; its pointing part is
    what the centroid measures."""
    shaped = [c for c in cases if c.has_shape()]
    return [a.combined(b) for i, a in enumerate(shaped) for b in shaped[i + 1:]]


def _twist(x, y):
    return 6e-3 * y, np.zeros_like(y)


def _canting(x, y):
    on = (x > 0) & (y > 0)
    return np.where(on, -6e-3, 0.0), np.where(on, -6e-3, 0.0)


def _sag(x, y):
    return np.zeros_like(x), y / 200.0


def _split(x, y):
    return np.where(x > 0, 6e-3, -6e-3), np.zeros_like(y)


CASES: tuple[ErrorCase, ...] = (
    ErrorCase("tracking-offset", TrackingErrorParams(az_offset=3e-3, el_offset=-2e-3, tilt_east=2e-3)),
    ErrorCase("wind-load", TrackingErrorParams(el_offset=1e-3), deformation=_twist),
    ErrorCase("gear-backlash", TrackingErrorParams(az_offset=2e-3), rock_az_rad=60e-3),
    ErrorCase("canting-error", deformation=_canting),
    ErrorCase("gravity-sag", TrackingErrorParams(el_offset=-1e-3), deformation=_sag),
    ErrorCase("facet-split", deformation=_split),
    ErrorCase("defocus", focus_factor=1.6),
)


@dataclass(frozen=True)
class Scene:
    """Fixed geometry of the error-set plant: heliostat, source, target frame."""

    kin: HeliostatKinematics
    mirror: MirrorSurface
    source_pos: np.ndarray
    source_diameter_rad: float
    aim_point: np.ndarray
    target_normal: np.ndarray
    u_axis: np.ndarray
    v_axis: np.ndarray
    sensor: SensorModel
    exposures: tuple[float, float]
    camera: Camera  # the configured camera the sensor model and the HDR merge follow
    heliostat: str = ""
    source: str = ""  # light source id of the config

    @property
    def slant_m(self) -> float:
        """Distance heliostat -> aim point (m)."""
        return float(np.linalg.norm(self.aim_point - self.kin.position))


def scene_from_config(cfg: PlantConfig, heliostat_id: str = "H09", source_id: str | None = None) -> Scene:
    """Heliostat ``heliostat_id`` aimed at the calibration target's centre under the light
    source ``source_id`` (default: the calibration's, the lamp in the demo)."""
    h = cfg.heliostat(heliostat_id)
    target = cfg.target(cfg.calibration.target)
    src = cfg.light_source(source_id or cfg.calibration.light_source)
    pos = np.asarray(h.position_enu_m, dtype=float)
    if getattr(src, "kind", "") == "lamp":
        source_pos = np.asarray(src.position_enu_m, dtype=float)
        diameter = float(src.diameter_m) / float(np.linalg.norm(source_pos - pos))
    else:  # the sun overhead-ish, far away: a point 1e6 m along the zenith-south direction
        source_pos = pos + 1e6 * unit(np.array([0.0, -0.5, 1.0]))
        diameter = float(src.angular_diameter_mrad) * 1e-3
    grid = TargetGrid.from_target(target, (GRID_PX, GRID_PX))
    cam = cfg.camera
    sensor = SensorModel(bit_depth=cam.bit_depth, dark_offset=cam.dark_offset_counts,
                         read_noise=cam.read_noise_counts, full_well=cam.full_well_electrons)
    return Scene(HeliostatKinematics.from_config(h), MirrorSurface.from_config(h.mirror), source_pos,
                 diameter, np.asarray(target.center_enu_m, dtype=float), grid.normal, grid.u_axis,
                 grid.v_axis, sensor, (cam.sensors[0].exposure_s, cam.sensors[1].exposure_s), cam,
                 heliostat=h.id, source=src.id)


@dataclass(frozen=True)
class View:
    """Framing and exposure of one rendered image (all zero/one = the library's nominal view)."""

    shift_m: tuple[float, float] = (0.0, 0.0)
    scale: float = 1.0
    rotation_rad: float = 0.0
    exposure_factor: float = 1.0
    seed: int = 0


def perturbed_views(seed: int, label_index: int, n: int, stream: int = 0) -> list[View]:
    """Deterministic test views for one case: translation, scaling, rotation, exposure, noise.
    ``stream`` > 0 draws an independent sequence (another heliostat of the same error set)."""
    rng = np.random.default_rng([seed, 1000 + label_index] + ([stream] if stream else []))
    return [View(shift_m=(float(rng.uniform(-0.3, 0.3)), float(rng.uniform(-0.3, 0.3))),
                 scale=float(np.exp(rng.uniform(np.log(0.8), np.log(1.25)))),
                 rotation_rad=float(rng.uniform(0.0, 2 * np.pi)),
                 exposure_factor=float(np.exp(rng.uniform(np.log(0.6), np.log(1.5)))),
                 seed=int(rng.integers(1 << 31))) for _ in range(n)]


def beam_error_deg(scene: Scene, case: ErrorCase) -> tuple[float, float]:
    """(Δazimuth, Δelevation) in degrees of the reflected beam caused by the case's pointing."""
    ideal_n, actual_n = _normals(scene, case)
    s = unit(scene.source_pos - scene.kin.position)
    beams = [2.0 * (s @ n) * n - s for n in (ideal_n, actual_n)]
    (az0, el0), (az1, el1) = (vector_to_azel(b) for b in beams)
    return float((az1 - az0 + 180.0) % 360.0 - 180.0), float(el1 - el0)


def _normals(scene: Scene, case: ErrorCase) -> tuple[np.ndarray, np.ndarray]:
    s = unit(scene.source_pos - scene.kin.position)
    ideal = unit(s + unit(scene.aim_point - scene.kin.position))
    alpha, eps = angles_from_normal(ideal)
    return ideal, actual_normal_from_angles(case.params, alpha, eps)


def render_irradiance(scene: Scene, case: ErrorCase, view: View) -> np.ndarray:
    """Relative irradiance (rows, cols) on the view's target grid for one case."""
    rng = np.random.default_rng(view.seed)
    ideal_n, actual_n = _normals(scene, case)
    c, s = np.cos(view.rotation_rad), np.sin(view.rotation_rad)
    u = c * scene.u_axis + s * scene.v_axis
    v = -s * scene.u_axis + c * scene.v_axis
    side = GRID_M * view.scale
    grid = TargetGrid(scene.aim_point + view.shift_m[0] * scene.u_axis + view.shift_m[1] * scene.v_axis,
                      scene.target_normal, u, v, side, side, (GRID_PX, GRID_PX))
    mirror = replace(scene.mirror, deformation=case.deformation,
                     focal_length_m=scene.mirror.focal_length_m / case.focus_factor)
    if case.rock_az_rad == 0.0:
        poses = [actual_n]
    else:
        alpha, eps = angles_from_normal(ideal_n)
        # Gusts sweep the mirror across the whole dead band during the exposure: uniform dwell.
        offsets = np.linspace(-0.5, 0.5, 15) * case.rock_az_rad
        poses = [actual_normal_from_angles(replace(case.params, az_offset=case.params.az_offset + d),
                                           alpha, eps) for d in offsets]
    rays = max(1, N_RAYS // len(poses))
    # Irradiance (W/m² per W/m²) does not depend on the pixel footprint, and neither does the
    # camera's pixel value (radiance of a Lambertian target), so the zoom needs no rescaling.
    return sum(render_spot(scene.kin.position, n, scene.source_pos, scene.source_diameter_rad, mirror, grid,
                           rng=rng, n_rays=rays) for n in poses) / len(poses)


def expose_and_merge(scene: Scene, irradiance: np.ndarray, view: View, reference_peak: float,
                     merger: HdrMerger) -> np.ndarray:
    """Double-CCD pair of the irradiance and its HDR merge (float32, counts / s).

    ``reference_peak`` is the peak irradiance of the case's nominal view: the camera is set up
    per heliostat so that it peaks at 1.2x the HIGH sensor's full scale (HIGH saturates in the
    core, LOW does not). ``view.exposure_factor`` (0.6-1.5) then scales the signal as a change
    of exposure would, so some views saturate HIGH and none saturates LOW. A dim ambient
    pedestal (0.5 % of the peak) plus a gradient stands for stray light on the target.
    """
    rng = np.random.default_rng(view.seed + 1)
    t_low, t_high = scene.exposures
    counts_per_s = 1.2 * scene.sensor.span / t_high / reference_peak
    rows, cols = irradiance.shape
    yy, xx = np.mgrid[0:rows, 0:cols]
    ambient = reference_peak * (0.005 + 0.002 * xx / cols + 0.001 * yy / rows)
    e = (irradiance + ambient) * counts_per_s * view.exposure_factor
    low = scene.sensor.expose(e, t_low, rng)
    high = scene.sensor.expose(e, t_high, rng)
    return merger.merge(low, high)


MANIFEST_EXTRA = ("heliostat", "source", "slant_m", "magnitude")


@dataclass(frozen=True)
class ErrorSet:
    library_manifest: Path
    test_manifest: Path
    labels: list[str]
    images: int


def write_errorset(out: str | Path, scene: Scene | Sequence[Scene], seed: int = 0, cases: int = 6,
                   views: int = 14, progress: Callable[[int, int], None] | None = None, *,
                   magnitudes: Sequence[float] = (1.0,), test_scenes: Sequence[Scene] | None = None,
                   test_magnitude_range: tuple[float, float] | None = None,
                   combined: bool = False) -> ErrorSet:
    """Render the library and the test views; write both manifests.

    Library: one nominal view per (case, scene, magnitude) for the scenes ``scene`` (one or
    several heliostat/source geometries) and ``magnitudes`` (multiples of the case's size).
    Test: ``views`` perturbed views per (case, test scene) for ``test_scenes`` (default: the
    library's); each view's magnitude is drawn uniformly from ``test_magnitude_range`` or, without
    it, taken in turn from ``magnitudes``. ``combined`` adds every pair of the chosen cases that
    both change the shape (:func:`shape_pairs`, labels ``"a+b"``) as cases of their own.

    Files: ``OUT/library.csv``, ``OUT/test.csv`` (``image,label,az_deg,el_deg`` with az/el = the
    state's beam pointing error in degrees, then ``heliostat,source,slant_m,magnitude``) and
    ``OUT/images/*.npy`` (float32 HDR), each with a PNG preview beside it.
    """
    if not 1 <= cases <= len(CASES):
        raise ValueError(f"cases must be in 1..{len(CASES)}")
    if not magnitudes or min(magnitudes) <= 0:
        raise ValueError("magnitudes must be positive")
    out = Path(out)
    lib_scenes = [scene] if isinstance(scene, Scene) else list(scene)
    test_scenes = lib_scenes if test_scenes is None else list(test_scenes)
    chosen = CASES[:cases] + (tuple(shape_pairs(CASES[:cases])) if combined else ())
    multi = len(lib_scenes) > 1 or len(test_scenes) > 1 or len(magnitudes) > 1
    mergers: dict[tuple[float, float], HdrMerger] = {}
    lib_rows, test_rows = [], []
    total = len(chosen) * (len(lib_scenes) * len(magnitudes) + len(test_scenes) * views)
    done = 0
    peaks: dict[tuple, float] = {}

    def emit(kind: str, case_i: int, sc: Scene, m: float, view: View, k: int, rows: list) -> None:
        nonlocal done
        case = chosen[case_i].scaled(m) if m != 1.0 else chosen[case_i]
        key = (case_i, sc.heliostat, sc.source, m)
        if key not in peaks:  # the camera is set up on the state's nominal view
            peaks[key] = float(render_irradiance(sc, case, View(seed=seed)).max())
        if sc.exposures not in mergers:
            mergers[sc.exposures] = HdrMerger.from_camera_config(sc.camera, exposures=sc.exposures)
        merger = mergers[sc.exposures]
        hdr = expose_and_merge(sc, render_irradiance(sc, case, view), view, peaks[key], merger)
        tag = f"-{sc.heliostat}-{sc.source}-m{m:.3f}" if multi else ""
        name = f"images/{kind}-{case.label}{tag}-{k:02d}.npy"
        write_float_image(out / name, hdr)
        write_preview((out / name).with_suffix(".png"), hdr)  # for a person to look at
        az, el = beam_error_deg(sc, case)
        rows.append((name, case.label, f"{az:.6f}", f"{el:.6f}", sc.heliostat, sc.source, f"{sc.slant_m:.2f}",
                     f"{m:.4f}"))
        done += 1
        if progress:
            progress(done, total)

    for i in range(len(chosen)):
        for j, sc in enumerate(lib_scenes):
            for mi, m in enumerate(magnitudes):
                n = j * len(magnitudes) + mi
                emit("library", i, sc, float(m), View(seed=seed * 7919 + i + 104729 * n), n, lib_rows)
        for j, sc in enumerate(test_scenes):
            rng = np.random.default_rng([seed, 2000 + i, j])
            for k, v in enumerate(perturbed_views(seed, i, views, stream=j)):
                if test_magnitude_range is not None:
                    m = round(float(rng.uniform(*test_magnitude_range)), 4)
                else:
                    m = float(magnitudes[k % len(magnitudes)])
                emit("test", i, sc, m, v, (k + 1) if not multi else j * views + k, test_rows)
    header = ("image", "label", "az_deg", "el_deg", *MANIFEST_EXTRA)
    for fname, rows in (("library.csv", lib_rows), ("test.csv", test_rows)):
        write_manifest(out / fname, rows, header=header)
    return ErrorSet(out / "library.csv", out / "test.csv", [c.label for c in chosen], done)
