"""A campaign's camera registration rebuilt from its record, for re-analysing its stored pairs.

The archive keeps each measurement's raw LOW/HIGH frames. A campaign with
``camera.registration`` rectified them through the registration it made at its start
(:mod:`controller.calibration.cycle.registration_step`), whose poses the campaign record keeps
(``meta["camera_registration"]``: per sensor the Rodrigues ``rvec`` and ``tvec_m``). The
intrinsics were fixed to the lab calibration of the configuration, so configuration + record
give back the same camera models and the same rectification.
"""

from __future__ import annotations

import numpy as np

from controller.calibration.cycle.registration_step import CameraRegistration, nominal_camera
from controller.config import PlantConfig
from controller.errors import InputError
from controller.geometry.target_frame import TargetFrame
from controller.imaging.registration import CameraModel, Registration


def registration_from_record(cfg: PlantConfig, record: dict, frame: TargetFrame) -> CameraRegistration:
    """The :class:`CameraRegistration` a campaign recorded (``record`` = its
    ``meta["camera_registration"]``) under ``cfg`` (that campaign's target). InputError when the
    record is incomplete or the configuration has no ``camera.registration`` any more."""
    if cfg.camera.registration is None:
        raise InputError("a campaign was registered (camera_registration in its record) but the "
                         "configuration has no camera.registration now")
    nominal = nominal_camera(cfg)
    regs = []
    for sensor in ("low", "high"):
        try:
            r = record[sensor]
            rvec = np.asarray(r["rvec"], float).reshape(3)
            tvec = np.asarray(r["tvec_m"], float).reshape(3)
            rms = float(r["rms_px"])
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"camera_registration.{sensor}: incomplete record ({exc})") from None
        if not (np.isfinite(rvec).all() and np.isfinite(tvec).all()):
            raise InputError(f"camera_registration.{sensor}: non-finite pose")
        model = CameraModel(nominal.K, nominal.dist, rvec, tvec, nominal.image_size)
        regs.append(Registration(model, rms, np.zeros((0, 2)), "pose"))
    return CameraRegistration.build(regs[0], regs[1], frame, int(record.get("fiducials", 0)),
                                    cfg.camera.bit_depth)
