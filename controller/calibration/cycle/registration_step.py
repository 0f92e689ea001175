"""Camera-to-target registration at the start of a campaign (docs/camera.md, "Registration").

With ``camera.registration`` configured, the controller does not trust the camera to look at
the target as configured: it takes a *fiducial frame* — one capture with the target's fiducial
lamps off, one with them on (the difference keeps the fiducials only: no ambient light, no
stray beam) — finds every surveyed fiducial near where the nominal camera model puts it,
and fits each sensor's pose (:func:`controller.imaging.registration.register`, intrinsics
fixed to the lab calibration). A registration whose reprojection RMS exceeds
``camera.registration.max_rms_px``, or with fewer than 4 fiducials found, is refused.

The beam chain then rectifies both sensors onto the target frame before the HDR merge
(:meth:`CameraRegistration.rectify`): the merge sees two images of the *same* target pixels
(the sensors' misregistration is gone), and the beam analysis, the centroid → ENU map and the
Hu moments of recognition all work in the rectified view they were written for.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from controller.config import PlantConfig
from controller.devices.camera import DoubleCcdCamera, FramePair
from controller.devices.file_camera import FileCamera
from controller.devices.lamp_drivers import fiducial_switch
from controller.devices.plant_time import WALL, PlantTime
from controller.errors import HeliocalError
from controller.geometry.target_frame import TargetFrame
from controller.imaging.fiducials import detect_fiducials, look_at_pose, rectify_sensor
from controller.imaging.registration import CameraModel, Registration, rectification_maps, register

SENSORS = ("low", "high")


class RegistrationError(HeliocalError):
    """The camera could not be registered to the target (exit 1: the plant, not the input)."""


def nominal_camera(cfg: PlantConfig) -> CameraModel:
    """The camera model the configuration states: ``camera.registration``'s intrinsics and
    distortion, the pose from ``camera.position_enu_m`` looking at ``look_at_enu_m`` (default
    the calibration target's centre)."""
    cam = cfg.camera
    reg = cam.registration
    if reg is None or cam.position_enu_m is None:
        raise RegistrationError("camera.registration: not configured")
    w, h = cam.width_px, cam.height_px
    cx, cy = reg.principal_point_px if reg.principal_point_px is not None else ((w - 1) / 2, (h - 1) / 2)
    k = np.array([[reg.focal_px, 0.0, cx], [0.0, reg.focal_px, cy], [0.0, 0.0, 1.0]])
    look = reg.look_at_enu_m if reg.look_at_enu_m is not None else cfg.target().center_enu_m
    rvec, tvec = look_at_pose(cam.position_enu_m, look, reg.roll_mrad * 1e-3)
    k1, k2, p1, p2 = reg.distortion
    return CameraModel(k, np.array([k1, k2, p1, p2, 0.0]), rvec, tvec, (w, h))


@dataclass(frozen=True, eq=False)  # numpy fields
class CameraRegistration:
    """Both sensors' registrations (LOW, HIGH) and their remap tables onto ``frame``."""

    low: Registration
    high: Registration
    frame: TargetFrame
    maps: tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
    found: int  # fiducials found in both sensors
    saturated_at: int

    @classmethod
    def build(cls, low: Registration, high: Registration, frame: TargetFrame, found: int,
              bit_depth: int) -> CameraRegistration:
        """Precompute the remap tables once (a projection per target pixel): a pair then costs
        two ``cv2.remap`` calls."""
        maps = (rectification_maps(low.model, frame), rectification_maps(high.model, frame))
        return cls(low, high, frame, maps, found, (1 << bit_depth) - 1)

    def rectify(self, frame: FramePair) -> tuple[np.ndarray, np.ndarray]:
        """(LOW, HIGH) of ``frame`` resampled onto the target frame, saturation kept
        (:func:`controller.imaging.fiducials.rectify_sensor`)."""
        return (rectify_sensor(frame.low, self.maps[0], self.saturated_at),
                rectify_sensor(frame.high, self.maps[1], self.saturated_at))

    def to_json(self) -> dict:
        """What the campaign record keeps: per sensor the RMS (px), the pose (Rodrigues rad,
        m) and the camera centre (m ENU); the number of fiducials used."""
        def one(r: Registration) -> dict:
            return {"rms_px": round(r.rms_px, 4), "rvec": [float(x) for x in r.model.rvec],
                    "tvec_m": [float(x) for x in r.model.tvec],
                    "center_enu_m": [round(float(x), 4) for x in r.model.center_enu]}
        return {"fiducials": self.found, "low": one(self.low), "high": one(self.high)}


def fiducial_frame(camera: DoubleCcdCamera, lamps: Callable[[bool], None]) -> tuple[FramePair, FramePair]:
    """(dark, lit): a capture with the fiducial lamps off, then one with them on. ``lamps(on)``
    switches them (an operator or the plant's lamp controller; the simulated plant in
    simulation) and is always left off."""
    lamps(False)
    dark = camera.capture()
    try:
        lamps(True)
        lit = camera.capture()
    finally:
        lamps(False)
    return dark, lit


def register_camera(cfg: PlantConfig, camera: DoubleCcdCamera, lamps: Callable[[bool], None],
                    frame: TargetFrame, time: PlantTime = WALL) -> CameraRegistration:
    """Register both sensors of ``camera`` to the target's fiducials (module docstring).
    The fiducial lamps are switched by the plant's lamp panel or ``lamp_command`` when
    configured, else by ``lamps`` (:func:`controller.devices.lamp_drivers.fiducial_switch`).
    RegistrationError names the sensor and what failed."""
    reg_cfg = cfg.camera.registration
    nominal = nominal_camera(cfg)
    with fiducial_switch(cfg, lamps, time) as switch:
        dark, lit = fiducial_frame(camera, switch)
    pts = np.asarray(reg_cfg.fiducials_enu_m, float)
    predicted = nominal.project(pts)
    # A search disc never reaches halfway to a neighbour's nominal pixel: each disc holds one
    # fiducial, whatever the configured radius.
    gaps = np.hypot(*(predicted[:, None, :] - predicted[None, :, :]).transpose(2, 0, 1))
    radius = min(reg_cfg.search_radius_px, 0.45 * float(gaps[~np.eye(len(pts), dtype=bool)].min()))
    regs = []
    found = len(pts)
    for k, name in enumerate(SENSORS):
        diff = (np.asarray((lit.low, lit.high)[k], float) - np.asarray((dark.low, dark.high)[k], float))
        px = detect_fiducials(diff, predicted, radius)
        ok = np.isfinite(px).all(axis=1)
        if ok.sum() < 4:
            raise RegistrationError(
                f"camera registration: {name.upper()} sensor sees {int(ok.sum())} of {len(pts)} fiducials "
                f"within {radius:.0f} px of their nominal pixels (needs 4); are the "
                "fiducial lamps lit and camera.position_enu_m / camera.registration right?")
        try:
            regs.append(register(pts[ok], px[ok], nominal.image_size, fix_intrinsics=nominal,
                                 max_rms_px=reg_cfg.max_rms_px))
        except HeliocalError as exc:
            bound = " (camera.registration.max_rms_px)" if "exceeds" in str(exc) else ""
            raise RegistrationError(f"camera registration of the {name.upper()} sensor refused: {exc}{bound}"
                                    ) from None
        found = min(found, int(ok.sum()))
    return CameraRegistration.build(regs[0], regs[1], frame, found, cfg.camera.bit_depth)


def register_chain(cfg: PlantConfig, camera: DoubleCcdCamera, chain, lamps: Callable[[bool], None],
                   meta: dict, lock, time: PlantTime = WALL) -> None:
    """With ``camera.registration`` configured: register ``camera`` (holding ``lock``, the
    camera's), make ``chain`` (a BeamChain) rectify through it and keep the result in the
    campaign metadata ``meta["camera_registration"]`` (:meth:`CameraRegistration.to_json`).
    Without it, or for recorded pairs (a :class:`FileCamera`: they are rectified views, and a
    replay has no fiducial lamps to switch), nothing happens: the pairs are taken as rectified."""
    if cfg.camera.registration is None or isinstance(camera, FileCamera):
        return
    with lock:
        chain.registration = register_camera(cfg, camera, lamps, chain.frame, time)
    meta["camera_registration"] = chain.registration.to_json()
