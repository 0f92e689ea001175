"""Field commissioning of one heliostat: jog, capture and look, store reference cases, verify.

The steps (used by ``heliocal commission``, interactive or one flag per step):

* :meth:`Commissioning.status`, :meth:`jog`, :meth:`move`, :meth:`aim` (to the target centre,
  with the heliostat's fitted model when a database gives one), :meth:`park` (standby);
* :meth:`capture`: one double-CCD pair → HDR merge → beam analysis; :meth:`save_png` writes
  the HDR frame as an 8-bit PNG (scaled to its peak) for a person to look at;
* :meth:`store_reference`: saves the HDR frame (``.npy``) and adds it to an error library
  YAML as a reference case with a label (features from its Hu moments, sha256 of the file),
  and appends it to the library's manifest CSV so a rebuild
  (``heliocal library build``) includes it and recalibrates the unknown threshold;
* :meth:`verify`: capture and report the reflected-beam pointing error against the aim point
  (the beam centroid on the target, mrad) and whether it is within the tolerance.

Nothing here knows whether the drive or camera is simulated.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controller.calibration.cycle.beam_chain import BeamChain
from controller.calibration.cycle.observations import BeamNotFound, NoBeam, Observation
from controller.calibration.cycle.park import park
from controller.calibration.cycle.pointing import GeometryPointing
from controller.calibration.cycle.registration_step import register_chain
from controller.config import PlantConfig
from controller.devices.drive import DRIVE_TIME
from controller.devices.plant_time import PlantTime
from controller.errors import HeliocalError, InputError
from controller.geometry.aiming import pointing_error_mrad
from controller.io.images import write_preview


@dataclass
class Capture:
    frame: object  # FramePair
    hdr: np.ndarray
    observation: Observation | None
    problem: str | None = None  # why there is no observation
    # The presence decision found no beam (statistic, threshold): nothing is computed from it.
    no_beam: tuple[float, float] | None = None

    def to_json(self, aim_point, heliostat_pos) -> dict:
        o = self.observation
        if o is None:
            nb = {} if self.no_beam is None else {"statistic": self.no_beam[0], "threshold": self.no_beam[1]}
            return {"beam": False, "no_beam": self.no_beam is not None, **nb, "problem": self.problem,
                    "exposures": list(self.frame.exposures)}
        return {"beam": True, "centroid_px": list(o.centroid_px), "centroid_enu_m": list(o.centroid_enu),
                "error_mrad": pointing_error_mrad(heliostat_pos, aim_point, o.centroid_enu),
                "peak": o.peak, "exposures": list(self.frame.exposures)}


class Commissioning:
    """One heliostat's commissioning session over a drive and a camera. ``fiducial_lamps(on)``
    (a live camera whose configuration has ``camera.registration``): register the camera to
    the target's fiducials first, as a campaign does (docs/camera.md, "Registration"); without
    it the pairs are taken as rectified (recorded pairs)."""

    def __init__(self, cfg: PlantConfig, heliostat_id: str, drive, camera, *, library=None,
                 model=None, move_timeout_s: float = 300.0, fiducial_lamps=None,
                 time: PlantTime = DRIVE_TIME) -> None:
        self.cfg = cfg
        self.h = cfg.heliostat(heliostat_id)
        self.drive = drive
        self.camera = camera
        self.chain = BeamChain(cfg, library)
        if fiducial_lamps is not None:  # a live camera: register it as a campaign does
            register_chain(cfg, camera, self.chain, fiducial_lamps, {}, contextlib.nullcontext())
        st = drive.status()
        self.pointing = GeometryPointing(self.h, cfg.target(), cfg.light_source(), self.chain.frame,
                                         cfg.calibration.standby_offset_m, (st.az_steps, st.el_steps),
                                         cfg.calibration.model, others=cfg.targets, zones=cfg.person_zones)
        self.model = model
        self.move_timeout_s = move_timeout_s
        self.time = time
        self.last: Capture | None = None
        # Whether this session moved the heliostat away from where it parked it last: an
        # operator command must not end with the beam wherever the session left it.
        self.needs_parking = False

    # -- motion ---------------------------------------------------------------------------------
    def status(self) -> dict:
        return self.drive.status().to_json()

    def move(self, az_steps: int, el_steps: int) -> dict:
        self.needs_parking = True
        st = self.drive.move_and_wait(int(az_steps), int(el_steps), timeout_s=self.move_timeout_s,
                                      time=self.time)
        return st.to_json()

    def jog(self, daz_steps: int, del_steps: int) -> dict:
        """Relative move from the present target, sent as the absolute move it amounts to (so
        the soft-limit check and the wait are those of :meth:`move`)."""
        st = self.drive.status()
        return self.move(st.az_target + int(daz_steps), st.el_target + int(del_steps))

    def aim(self) -> dict:
        """Park at standby first (approach from standby), then move onto the aim point."""
        self.park()
        az, el = self.pointing.aim_steps(self.model)
        return self.move(az, el)

    def park(self) -> dict:
        out = park(self.drive, self.pointing, self.pointing.standby_steps(self.model), self.move)
        self.needs_parking = False
        return out if isinstance(out, dict) else out.to_json()

    def make_safe(self) -> dict:
        """End of session: park at standby along a beam-safe path; if that fails, stop the
        axes where they are. Returns what was done (``action``: parked / stopped / failed)."""
        try:
            return {"action": "parked", **self.park()}
        except HeliocalError as exc:
            try:
                self.drive.stop()
                return {"action": "stopped", "reason": f"standby failed: {exc}",
                        **self.drive.status().to_json()}
            except HeliocalError as second:
                return {"action": "failed", "reason": f"standby failed: {exc}; stop failed: {second}"}

    # -- camera ---------------------------------------------------------------------------------
    def capture(self) -> Capture:
        frame = self.camera.capture()
        hdr = self.chain.merge(frame)
        no_beam = None
        try:
            obs, problem = self.chain.analyze(hdr), None
        except NoBeam as exc:
            obs, problem, no_beam = None, str(exc), (exc.statistic, exc.threshold)
        except BeamNotFound as exc:
            obs, problem = None, str(exc)
        self.last = Capture(frame, hdr, obs, problem, no_beam)
        return self.last

    @staticmethod
    def save_png(hdr: np.ndarray, path: str | Path) -> Path:
        """The HDR frame as an 8-bit grey PNG scaled to its 99.9th percentile (for a person)."""
        return write_preview(path, hdr)

    def store_reference(self, label: str, library_path: str | Path, capture: Capture | None = None) -> dict:
        """Add the (last) captured frame to the library as a reference case ``label``."""
        from controller.recognition.library_io import add_reference

        cap = capture or self.last or self.capture()
        if cap.observation is None:
            raise InputError(f"cannot store a reference case: {cap.problem}")
        return add_reference(library_path, label, cap.hdr, cap.observation.hu, source=self.h.id,
                             threshold=self.cfg.calibration.threshold)

    def verify(self) -> dict:
        """Capture and score the pointing error against the aim point (target centre)."""
        cap = self.capture()
        out = cap.to_json(self.pointing.aim_point, self.pointing.heliostat_pos)
        tol = self.cfg.calibration.tolerance_mrad
        out["tolerance_mrad"] = tol
        out["ok"] = bool(out.get("beam")) and out["error_mrad"] <= tol
        if cap.observation is not None and self.chain.library is not None:
            m = self.chain.match(cap.observation)
            out["match"] = {"label": "unknown" if m.unknown else m.label, "distance": m.distance}
        return out
