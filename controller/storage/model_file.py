"""MODEL.json: a fitted tracking model of one heliostat, as ``heliocal model fit`` writes it
and ``heliocal model predict`` reads it (format in docs/tracking-model.md).

The file carries everything a prediction needs — the heliostat's properties (PAINT/ARTIST
format), the plant origin, the fitted terms with σ and covariance — so it can be used
without the files it was fitted from.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from controller.errors import InputError
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model.drift import DRIFTING, RandomWalk, offsets_at
from controller.geometry.model.field_prior import FieldPrior
from controller.geometry.model.fit import ModelFit
from controller.geometry.model.tracking import NAMES, PRIOR_SIGMA_SI, TERMS, TrackingModel
from controller.geometry.paint_io import check_heliostat_properties, kinematics_from_properties
from controller.io.images import write_atomic
from controller.io.json_files import dumps_json, parse_json
from controller.io.yaml_files import read_text

FORMAT = "heliocal-tracking-model/1"


@dataclass(frozen=True, eq=False)  # numpy field
class ModelFile:
    """A loaded MODEL.json: heliostat id and properties, plant origin, model and covariance,
    and, for a fit to timed records, the time of its newest session (``reference_days``, days
    since 1970 UTC) and the references' random walk (``walk``) the model drifts by since."""

    heliostat_id: str
    properties: dict
    origin_wgs84: tuple[float, float, float]
    model: TrackingModel
    covariance: np.ndarray
    reference_days: float | None = None
    walk: RandomWalk | None = None
    identified: tuple[str, ...] = ()
    session_days: np.ndarray | None = None
    session_offsets_mrad: np.ndarray | None = None

    def model_at(self, days: float | None) -> TrackingModel:
        """The model at time ``days`` (days since 1970 UTC): its references moved by the drift
        the fit found then (:func:`controller.geometry.model.drift.offsets_at`); as fitted
        after its newest session, at an unknown time or without drift."""
        if self.session_days is None or days is None:
            return self.model
        values = self.model.values.copy()
        values[[NAMES.index(n) for n in DRIFTING]] += 1e-3 * offsets_at(self.session_days,
                                                                        self.session_offsets_mrad, days)
        return TrackingModel(values)

    def kinematics(self) -> HeliostatKinematics:
        return kinematics_from_properties(self.properties, self.origin_wgs84, self.heliostat_id)


def _utc(days: float) -> str:
    return datetime.fromtimestamp(days * 86400.0, UTC).isoformat(timespec="seconds")


def model_document(heliostat_id: str, properties: dict, origin_wgs84, fit: ModelFit, *, noise_mrad: float,
                   records: list[str], prior: FieldPrior | None = None, prior_source: str = "default",
                   walk: RandomWalk | None = None, times: list[float | None] | None = None) -> dict:
    """The JSON document of a fit (see docs/tracking-model.md): ``prior`` the field prior it
    was fitted with (None: the documented one), ``walk`` the references' random walk and
    ``times`` (days since 1970 UTC) the records' times, when it had them."""
    mean = TrackingModel(prior.mean if prior else np.zeros(len(TERMS))).to_dict()
    sig = PRIOR_SIGMA_SI if prior is None else prior.sigma
    drift = None
    if fit.session_times is not None and walk is not None:
        drift = {"sigma_mrad_per_sqrt_day": 1e3 * walk.sigma_per_sqrt_day, "jump_mrad": 1e3 * walk.jump,
                 "gap_days": walk.gap_days, "reference_time_utc": _utc(float(fit.session_times[-1])),
                 "sessions": [{"time_utc": _utc(float(t)), "az_offset_mrad": float(d[0]),
                               "el_offset_mrad": float(d[1])}
                              for t, d in zip(fit.session_times, fit.drift_mrad, strict=True)]}
    return {
        "format": FORMAT,
        "heliostat": {"id": heliostat_id, "properties": properties},
        "origin_wgs84": [float(v) for v in origin_wgs84],
        "terms": fit.model.to_dict(),
        "sigma": fit.sigma_dict(),
        "prior_sigma": {t.key: 1e3 * float(v) for t, v in zip(TERMS, sig, strict=True)},
        "prior": {"source": prior_source, "terms": mean},
        "identified": fit.identified_terms(),
        "covariance_si": fit.covariance.tolist(),
        "noise_mrad": noise_mrad,
        "noise_scale": fit.noise_scale,
        "condition": fit.condition,
        "converged": fit.converged,
        "drift": drift,
        "notes": list(fit.notes),
        "training": {
            "records": records,
            "times_utc": None if times is None else [None if t is None else _utc(t) for t in times],
            "residual_mrad": [float(r) for r in fit.residual_mrad],
            "residual_mrad_rms": fit.residual_mrad_rms,
            "initial_residual_mrad_rms": fit.initial_residual_mrad_rms,
            "robust_weights": [float(w) for w in fit.weights],
        },
    }


def write_model(path: str | Path, document: dict) -> None:
    """Write atomically (nothing half-written on failure)."""
    text = dumps_json(document, indent=1)
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
    ref, walk, sessions = _drift(data.get("drift"), src)
    identified = data.get("identified", [])
    if not (isinstance(identified, list) and all(n in NAMES for n in identified)):
        raise InputError(f"{src}: identified must list term names (known: {', '.join(NAMES)})")
    return ModelFile(hid, props, tuple(float(v) for v in origin), model, c, ref, walk,  # type: ignore[arg-type]
                     tuple(identified), *sessions)


def _days(text, src: str, key: str) -> float:
    try:
        t = datetime.fromisoformat(str(text).replace("Z", "+00:00"))
    except ValueError:
        t = None
    if t is None or t.tzinfo is None:
        raise InputError(f"{src}: {key} must be an ISO 8601 time with its offset, got {str(text)[:40]!r}")
    return t.timestamp() / 86400.0


def _drift(drift, src: str) -> tuple[float | None, RandomWalk | None, tuple]:
    """(reference time in days, walk, (session days, their offsets in mrad)) of a model's
    ``drift`` key (absent or null: none)."""
    if drift is None:
        return None, None, (None, None)
    try:
        sigma, jump = float(drift["sigma_mrad_per_sqrt_day"]), float(drift["jump_mrad"])
        gap = float(drift["gap_days"])
        ref = _days(drift["reference_time_utc"], src, "drift.reference_time_utc")
        sessions = drift["sessions"]
        days = np.array([_days(s["time_utc"], src, "drift.sessions[].time_utc") for s in sessions])
        offsets = np.array([[float(s["az_offset_mrad"]), float(s["el_offset_mrad"])] for s in sessions])
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{src}: drift must hold sigma_mrad_per_sqrt_day, jump_mrad, gap_days, "
                         f"reference_time_utc and sessions ({exc})") from None
    if not all(math.isfinite(v) and v >= 0 for v in (sigma, jump, gap)) or not np.all(np.isfinite(offsets)):
        raise InputError(f"{src}: drift has a negative or non-finite value")
    if len(days) == 0 or np.any(np.diff(days) < 0):
        raise InputError(f"{src}: drift.sessions must list sessions in time order")
    return ref, RandomWalk(sigma * 1e-3, jump * 1e-3, gap), (days, offsets.reshape(-1, len(DRIFTING)))
