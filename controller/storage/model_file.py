"""MODEL.json: a fitted tracking model of one heliostat, as ``heliocal model fit`` writes it
and ``heliocal model predict`` reads it (format in docs/tracking-model.md).

The file carries everything a prediction needs — the heliostat's properties (PAINT/ARTIST
format), the plant origin, the fitted terms with σ and covariance — so it can be used
without the files it was fitted from.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controller.errors import InputError
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model_fit import ModelFit
from controller.geometry.paint_io import check_heliostat_properties, kinematics_from_properties
from controller.geometry.tracking_model import TERMS, TrackingModel
from controller.io.images import write_atomic
from controller.io.json_files import parse_json
from controller.io.yaml_files import read_text

FORMAT = "heliocal-tracking-model/1"


@dataclass(frozen=True, eq=False)  # numpy field
class ModelFile:
    """A loaded MODEL.json: heliostat id and properties, plant origin, model and covariance."""

    heliostat_id: str
    properties: dict
    origin_wgs84: tuple[float, float, float]
    model: TrackingModel
    covariance: np.ndarray

    def kinematics(self) -> HeliostatKinematics:
        return kinematics_from_properties(self.properties, self.origin_wgs84, self.heliostat_id)


def model_document(heliostat_id: str, properties: dict, origin_wgs84, fit: ModelFit, *, noise_mrad: float,
                   records: list[str]) -> dict:
    """The JSON document of a fit (see docs/tracking-model.md)."""
    return {
        "format": FORMAT,
        "heliostat": {"id": heliostat_id, "properties": properties},
        "origin_wgs84": [float(v) for v in origin_wgs84],
        "terms": fit.model.to_dict(),
        "sigma": fit.sigma_dict(),
        "prior_sigma": {t.key: t.prior_sigma for t in TERMS},
        "identified": fit.identified_terms(),
        "covariance_si": fit.covariance.tolist(),
        "noise_mrad": noise_mrad,
        "noise_scale": fit.noise_scale,
        "condition": fit.condition,
        "converged": fit.converged,
        "training": {
            "records": records,
            "residual_mrad": [float(r) for r in fit.residual_mrad],
            "residual_mrad_rms": fit.residual_mrad_rms,
            "initial_residual_mrad_rms": fit.initial_residual_mrad_rms,
            "robust_weights": [float(w) for w in fit.weights],
        },
    }


def write_model(path: str | Path, document: dict) -> None:
    """Write atomically (nothing half-written on failure)."""
    text = json.dumps(document, indent=1)
    write_atomic(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))


def read_model(path: str | Path) -> ModelFile:
    """Load and check a MODEL.json; InputError naming the file and key on any problem."""
    src = str(path)
    data = parse_json(read_text(path, "model file"), src)  # depth bounded before parsing
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise InputError(f"{src}: not a heliocal model file (expected \"format\": \"{FORMAT}\")")
    try:
        hel = data["heliostat"]
        hid, props = str(hel["id"]), hel["properties"]
        origin = data["origin_wgs84"]
        terms, cov = data["terms"], data["covariance_si"]
    except (KeyError, TypeError) as exc:
        raise InputError(f"{src}: missing key {exc}") from None
    if not isinstance(props, dict):
        raise InputError(f"{src}: heliostat.properties must be an object")
    check_heliostat_properties(props, f"{src}: heliostat.properties")
    if not (isinstance(origin, list) and len(origin) == 3
            and all(isinstance(v, int | float) and math.isfinite(v) for v in origin)):
        raise InputError(f"{src}: origin_wgs84 must be [lat, lon, alt]")
    if not isinstance(terms, dict):
        raise InputError(f"{src}: terms must be an object")
    model = TrackingModel.from_dict(terms, f"{src}: terms")
    n = len(TERMS)
    rows_ok = isinstance(cov, list) and all(isinstance(r, list) and len(r) == n for r in cov)
    if not (rows_ok and len(cov) == n):
        raise InputError(f"{src}: covariance_si must be a {n}×{n} matrix")
    try:
        c = np.asarray(cov, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{src}: covariance_si must hold numbers") from None
    if not np.all(np.isfinite(c)):
        raise InputError(f"{src}: covariance_si has a non-finite entry")
    return ModelFile(hid, props, tuple(float(v) for v in origin), model, c)  # type: ignore[arg-type]
