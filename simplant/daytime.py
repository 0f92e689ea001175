"""Open-loop daytime error of calibrated heliostats, scored against the simulated plant's truth.

For every heliostat and every sun position of the evaluation path
(:func:`controller.calibration.night.daytime.sun_path`): the controller computes the steps with the
heliostat's latest fitted model (:func:`controller.calibration.night.daytime.tracking_steps`, exactly
what ``heliocal aim`` does); the plant's hidden heliostat at those steps reflects the sun
about its true normal n from its true mirror centre c; the error is the angle between that
reflected ray, r = 2 (s·n) n − s, and the direction from c to the target centre, in mrad.
Nothing here was measured during the night: it is the figure calibration exists for.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controller.calibration.night.daytime import SunPath, sun_path, tracking_steps
from controller.calibration.records import ModelRecord
from controller.config import PlantConfig
from controller.geometry.aiming import angle_mrad


@dataclass(frozen=True)
class DaytimeError:
    """Reflected-beam errors (mrad) over all heliostats × sun positions they can reach:
    ``rms``, ``p95``, ``max``; ``per_heliostat`` RMS; ``samples`` counted."""

    rms: float
    p95: float
    max: float
    per_heliostat: dict[str, float]
    samples: int

    def to_json(self) -> dict:
        return {"rms": self.rms, "p95": self.p95, "max": self.max}


def true_errors_mrad(plant, heliostat_id: str, steps: np.ndarray, sun_dirs: np.ndarray,
                     target: np.ndarray) -> np.ndarray:
    """Reflected-beam error (n,) of the hidden heliostat at ``steps`` (n, 2) for sun directions
    (n, 3), against the direction to ``target`` (module docstring)."""
    out = np.empty(len(steps))
    for i, ((az, el), s) in enumerate(zip(steps, sun_dirs, strict=True)):
        n = plant.true_normal_at(heliostat_id, az, el)
        c = plant.true_mirror_center(heliostat_id, az, el)
        out[i] = angle_mrad(2.0 * float(s @ n) * n - s, target - c)
    return out


def daytime_error(plant, cfg: PlantConfig, models: dict[str, ModelRecord | None],
                  path: SunPath | None = None) -> DaytimeError:
    """:class:`DaytimeError` of the heliostats in ``models`` (id -> latest model, None: nominal)."""
    path = path or sun_path(cfg.site)
    target = np.asarray(cfg.target().center_enu_m, float)
    every, per = [], {}
    for hid, model in models.items():
        steps, ok = tracking_steps(cfg.heliostat(hid), model, path.directions, target)
        e = true_errors_mrad(plant, hid, steps[ok], path.directions[ok], target)
        per[hid] = float(np.sqrt(np.mean(e**2))) if e.size else float("nan")
        every.append(e)
    e = np.concatenate(every) if every else np.empty(0)
    if not e.size:
        nan = float("nan")
        return DaytimeError(nan, nan, nan, per, 0)
    rms = float(np.sqrt(np.mean(e**2)))
    return DaytimeError(rms, float(np.percentile(e, 95)), float(e.max()), per, int(e.size))
