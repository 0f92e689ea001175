"""The error library's reference views, rendered through the simulated plant's own camera."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.vectors import unit
from simplant.devices.plant_camera import PlantCamera
from simplant.errorset import CASES, beam_error_deg, scene_from_config
from simplant.firmware.physics import SimController
from simplant.optics import MirrorSurface
from simplant.plant import SimulatedPlant
from simplant.truth import hidden_truth


def write_reference_set(cfg_data: dict, out_dir: str | Path, heliostat_ids: list[str], *, seed: int = 0,
                        cases: int = 6, source: str = "<config>") -> Path:
    """Render the error library's reference views through the plant's own camera.

    For every reference heliostat and each of the first ``cases`` error-set cases: the
    heliostat with only that case (its pointing part and mirror shape, no random errors) aimed
    at the target centre with the nominal model, one frame pair, merged with the camera's true
    CRF, saved as ``images/<heliostat>-<case>.npy`` (float32 HDR). Several heliostats give each
    case several entries, so the nearest-neighbour match sees how the spot shape changes
    across the field. Returns the manifest ``library.csv`` (``image,label,az_deg,el_deg,magnitude``,
    az/el = the beam pointing error the case causes for that heliostat, degrees
    (:func:`simplant.errorset.beam_error_deg`), magnitude 1): what a match interpolates into
    the coarse correction.
    """
    import csv

    from controller.imaging.hdr import HdrMerger
    from controller.io.images import write_atomic, write_float_image

    out = Path(out_dir)
    plant = SimulatedPlant(cfg_data, out / "plant", heliostat_ids=list(heliostat_ids), seed=seed,
                           source=source)
    cfg = plant.cfg
    plant.camera = camera = PlantCamera(plant, cfg, seed=seed)
    cam = cfg.camera
    merger = HdrMerger.from_camera_config(cam, camera.true_crf(), exposures=camera.exposures)
    src = cfg.light_source()
    rows = []
    for hid in heliostat_ids:
        hh = plant.hidden[hid]
        h = cfg.heliostat(hid)
        kin = HeliostatKinematics.from_config(h)
        s = unit(np.asarray(src.position_enu_m, float) - kin.position)
        aim = kin.aim(s, np.asarray(cfg.target().center_enu_m, float))
        stow = hh.controller
        scene = scene_from_config(cfg, hid, src.id)
        for case in CASES[:cases]:
            # The reference heliostat is the surveyed one with only the case's own error.
            hh.case, hh.truth = case, hidden_truth(h, np.random.default_rng(0), 0.0, case)
            hh.mirror = replace(MirrorSurface.from_config(h.mirror), deformation=case.deformation,
                                focal_length_m=h.mirror.focal_length_m / case.focus_factor)
            hh.controller = SimController(unit=stow.unit, az=stow.az, el=stow.el, clock=plant.clock,
                                          initial_steps=aim)
            frame = camera.capture()
            name = f"images/{hid}-{case.label}.npy"
            write_float_image(out / name, merger.merge(frame.low, frame.high))
            az, el = beam_error_deg(scene, case)
            rows.append((name, case.label, f"{az:.6f}", f"{el:.6f}", f"{case.magnitude:.4f}"))
        hh.controller = stow

    def writer(tmp: Path) -> None:
        with open(tmp, "w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(["image", "label", "az_deg", "el_deg", "magnitude"])
            w.writerows(rows)

    write_atomic(out / "library.csv", writer)
    return out / "library.csv"
