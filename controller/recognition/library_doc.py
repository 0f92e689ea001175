"""The library document (YAML) <-> :class:`~controller.recognition.library.Library`: conversion and
validation (format in :mod:`controller.recognition.library`); the files themselves are read and
written by :mod:`controller.recognition.library_io`."""

from __future__ import annotations

import numpy as np

from controller.errors import InputError
from controller.recognition.features import FEATURE_KINDS, kind_thresholds, library_width
from controller.recognition.library import LIBRARY_VERSION, Entry, Library


def library_to_dict(lib: Library) -> dict:
    def entry(e: Entry) -> dict:
        d = {"label": e.label, "features": [float(v) for v in e.features], "az_deg": e.az_deg,
             "el_deg": e.el_deg, "sha256": e.sha256, "image": e.image,
             "unknown_distance": e.unknown_distance if np.isfinite(e.unknown_distance) else None}
        if e.correction is not None:
            d["correction"] = {"az_deg": float(e.correction["az_deg"]),
                               "el_deg": float(e.correction["el_deg"])}
        if e.params:
            d["params"] = {str(k): v for k, v in e.params.items()}
        return d

    norm = {"intensity": "unit-mean", "scale": [float(v) for v in lib.scale]}
    if lib.whiten is not None:
        norm["whiten"] = [[float(v) for v in row] for row in lib.whiten]
    doc = {"version": lib.version, "features": lib.features, "threshold": lib.threshold}
    if lib.features not in ("hu", "log-hu"):
        doc["thresholds"] = list(lib.thresholds)
    return doc | {
        "normalisation": norm,
        "widen": [float(f) for f in lib.widen],
        "unknown_distance": lib.unknown_distance if np.isfinite(lib.unknown_distance) else None,
        "entries": [entry(e) for e in lib.entries],
    }


def _vec(value, where: str, k: int = 7) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{where} must be a list of {k} numbers") from None
    if v.shape != (k,) or not np.all(np.isfinite(v)):
        raise InputError(f"{where} must be a list of {k} finite numbers")
    return v


def _opt_positive(value, where: str) -> float:
    """None -> inf (never unknown); else a positive number."""
    if value is None:
        return float("inf")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{where} must be a number") from None
    if not v > 0:
        raise InputError(f"{where} must be positive")
    return v


MAX_WIDEN = 8


def check_widen(value, where: str) -> tuple[float, ...]:
    """Absent (a library written before widening existed) -> none; else up to 8 numbers in (0, 1]."""
    if value is None:
        return ()
    if not isinstance(value, list) or len(value) > MAX_WIDEN:
        raise InputError(f"{where} must be a list of at most {MAX_WIDEN} numbers")
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise InputError(f"{where} must be a list of numbers") from None
    if not all(0.0 < v <= 1.0 for v in out):
        raise InputError(f"{where} must hold numbers in (0, 1] (σ as a fraction of the spot's d90)")
    return out


def library_from_dict(data: object, p: str) -> Library:
    """Validate a parsed library document (see the module docstring); errors name ``p`` (the
    file) and the key."""
    if not isinstance(data, dict):
        raise InputError(f"{p}: library must be a mapping")
    if data.get("version") != LIBRARY_VERSION:
        raise InputError(f"{p}: version: expected {LIBRARY_VERSION}, got {data.get('version')!r}")
    kind = data.get("features")
    if kind not in FEATURE_KINDS:
        raise InputError(f"{p}: features: must be one of {', '.join(FEATURE_KINDS)}, got {kind!r}")
    rows = list(kind_thresholds(kind, 0.5))
    if kind not in ("hu", "log-hu") and data.get("thresholds", rows) != rows:
        raise InputError(f"{p}: thresholds: a {kind} library uses {rows}")
    k = library_width(kind)
    norm = data.get("normalisation") or {}
    scale = _vec(norm.get("scale", [1.0] * k), f"{p}: normalisation.scale", k)
    if np.any(scale <= 0):
        raise InputError(f"{p}: normalisation.scale must be positive")
    whiten = None
    if norm.get("whiten") is not None:
        try:
            whiten = np.asarray(norm["whiten"], dtype=np.float64)
        except (TypeError, ValueError):
            whiten = None
        if whiten is None or whiten.shape != (k, k) or not np.all(np.isfinite(whiten)):
            raise InputError(f"{p}: normalisation.whiten must be a {k} x {k} matrix of finite numbers")
    raw_entries = data.get("entries")
    if not isinstance(raw_entries, list) or not raw_entries:
        raise InputError(f"{p}: entries: must be a non-empty list")
    entries = []
    for i, e in enumerate(raw_entries):
        where = f"{p}: entries[{i}]"
        if not isinstance(e, dict) or not e.get("label"):
            raise InputError(f"{where}.label: missing")
        corr = e.get("correction")
        if corr is not None and not (isinstance(corr, dict) and {"az_deg", "el_deg"} <= set(corr)):
            raise InputError(f"{where}.correction: must have az_deg and el_deg")
        unknown = _opt_positive(e.get("unknown_distance"), f"{where}.unknown_distance")
        params = e.get("params")
        if params is not None and not isinstance(params, dict):
            raise InputError(f"{where}.params: must be a mapping")
        entries.append(Entry(label=str(e["label"]), features=_vec(e.get("features"), f"{where}.features", k),
                             az_deg=e.get("az_deg"), el_deg=e.get("el_deg"), sha256=str(e.get("sha256", "")),
                             image=str(e.get("image", "")), correction=corr, unknown_distance=unknown,
                             params=params))
    unknown = data.get("unknown_distance")
    try:
        threshold = float(data.get("threshold", 0.5))
    except (TypeError, ValueError):
        raise InputError(f"{p}: threshold: must be a number") from None
    return Library(features=kind, threshold=threshold, entries=entries, scale=scale,
                   unknown_distance=float("inf") if unknown is None else float(unknown), whiten=whiten,
                   widen=check_widen(data.get("widen"), f"{p}: widen"))
