"""PRIOR.json: a field's prior of the tracking-model terms, as ``heliocal model prior`` writes
it and ``heliocal model fit --prior`` and the nights (``calibration.model.field_prior``) read it
(format in docs/tracking-model.md, "Field prior")."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from controller.errors import InputError
from controller.geometry.model.field_prior import FieldPrior
from controller.geometry.model.tracking import TERMS, TrackingModel
from controller.io.images import write_atomic
from controller.io.json_files import dumps_json, parse_json
from controller.io.yaml_files import read_text

FORMAT = "heliocal-field-prior/1"


def prior_document(prior: FieldPrior, heliostats: list[str]) -> dict:
    """The JSON document of a field prior learned from the models of ``heliostats``."""
    return {
        "format": FORMAT,
        "heliostats": heliostats,
        "terms": TrackingModel(prior.mean).to_dict(),
        "sigma": TrackingModel(prior.sigma).to_dict(),
        "identified_by": {t.key: int(c) for t, c in zip(TERMS, prior.count, strict=True)},
    }


def write_prior(path: str | Path, document: dict) -> None:
    """Write atomically (nothing half-written on failure)."""
    text = dumps_json(document, indent=1)
    write_atomic(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))


def read_prior(path: str | Path) -> FieldPrior:
    """Load and check a PRIOR.json; InputError naming the file and key on any problem."""
    src = str(path)
    data = parse_json(read_text(path, "field prior"), src)
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise InputError(f"{src}: not a heliocal field prior (expected \"format\": \"{FORMAT}\")")
    for key in ("terms", "sigma"):
        if not isinstance(data.get(key), dict):
            raise InputError(f"{src}: missing key '{key}' (an object of term values)")
    mean = TrackingModel.from_dict(data["terms"], f"{src}: terms").values
    given = TrackingModel.from_dict(data["sigma"], f"{src}: sigma")
    missing = [t.key for t in TERMS if t.key not in data["sigma"]]
    if missing:
        raise InputError(f"{src}: sigma lacks {', '.join(missing)}")
    if not np.all(given.values > 0):
        bad = next(t.key for t, v in zip(TERMS, given.values, strict=True) if not v > 0)
        raise InputError(f"{src}: sigma.{bad} must be > 0")
    counts = data.get("identified_by", {})
    count = np.array([int(counts.get(t.key, 0)) if isinstance(counts, dict)
                      and isinstance(counts.get(t.key, 0), int) else 0 for t in TERMS])
    if not all(math.isfinite(v) for v in mean):
        raise InputError(f"{src}: terms has a non-finite value")
    return FieldPrior(mean, given.values, count)
