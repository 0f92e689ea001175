"""The error library: reference beam images of known error cases, described by Hu features.

Manifest (CSV, header required): ``image,label,az_deg,el_deg``. ``az_deg``/``el_deg`` are
optional (columns may be absent or cells empty); image paths are relative to the manifest.
Images are merged HDR (``.npy`` / float ``.tiff``) or single grey PNG/TIFF.

Library (YAML)::

    version: 1
    features: hu | log-hu          # raw Hu (paper) or -sign(h) log10|h|
    threshold: 0.5                 # beam segmentation threshold used for every entry
    normalisation: {intensity: unit-mean, scale: [7 numbers]}
    unknown_distance: <float>      # largest per-entry threshold (informative)
    entries:
      - {label, features: [7], az_deg, el_deg, correction: {az_deg, el_deg} (optional), sha256, image,
         unknown_distance}         # per-entry threshold calibrated from the entry's own spread

Feature kinds:

* ``hu``: phi_1..phi_7 of the segmented spot at unit mean intensity, scale = 1 - the paper's
  raw Euclidean distance.
* ``log-hu``: l_i = -sign(phi_i) log10|phi_i| (|phi_i| floored at 1e-30 so an exact zero
  stays finite), scaled per feature by the standard deviation of the entries' values, so that
  the noisy phi_5..phi_7 of near-symmetric spots do not swamp the distance.
"""

from __future__ import annotations

import csv
import hashlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import yaml

from controller.calibration.matching import Matcher
from controller.errors import InputError
from controller.imaging.beam import analyze
from controller.io.images import read_image, write_atomic

LIBRARY_VERSION = 1
FEATURE_KINDS = ("hu", "log-hu")
_LOG_FLOOR = 1e-30


@dataclass(frozen=True)
class ManifestRow:
    image: Path
    label: str
    az_deg: float | None = None
    el_deg: float | None = None
    line: int = 0


@dataclass
class Entry:
    label: str
    features: np.ndarray
    az_deg: float | None = None
    el_deg: float | None = None
    sha256: str = ""
    image: str = ""
    correction: dict | None = None
    unknown_distance: float = float("inf")


@dataclass
class Library:
    features: str
    threshold: float
    entries: list[Entry]
    scale: np.ndarray = field(default_factory=lambda: np.ones(7))
    unknown_distance: float = float("inf")
    version: int = LIBRARY_VERSION

    @property
    def labels(self) -> list[str]:
        return [e.label for e in self.entries]

    def matrix(self) -> np.ndarray:
        return np.array([e.features for e in self.entries], dtype=np.float64).reshape(-1, 7)

    def matcher(self) -> Matcher:
        return Matcher(self.matrix(), self.labels, self.scale,
                       np.array([e.unknown_distance for e in self.entries], dtype=np.float64))


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def hu_features(hu: np.ndarray, kind: str) -> np.ndarray:
    """Feature vector (7,) from Hu moments: raw (``hu``) or signed log (``log-hu``)."""
    h = np.asarray(hu, dtype=np.float64)
    if kind == "hu":
        return h.copy()
    if kind == "log-hu":
        return -np.sign(h) * np.log10(np.maximum(np.abs(h), _LOG_FLOOR))
    raise InputError(f"feature kind must be one of {', '.join(FEATURE_KINDS)}, not {kind!r}")


def image_features(image: np.ndarray, kind: str, threshold: float = 0.5) -> np.ndarray:
    """Analyse a beam image (background auto) and return its feature vector (7,)."""
    return hu_features(analyze(image, threshold=threshold, background="auto").hu, kind)


def _opt_float(value: str | None, where: str, key: str) -> float | None:
    if value is None or value.strip() == "":
        return None
    try:
        v = float(value)
    except ValueError:
        raise InputError(f"{where}: {key} is not a number: {value!r}") from None
    if not np.isfinite(v):
        raise InputError(f"{where}: {key} must be finite, got {value!r}")
    return v


def write_manifest(path: str | Path, rows: list[tuple[str, str, str, str]] | list[list[str]]) -> None:
    """Write a manifest CSV (``image,label,az_deg,el_deg``, paths relative to it) atomically."""

    def writer(tmp: Path) -> None:
        with open(tmp, "w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(["image", "label", "az_deg", "el_deg"])
            w.writerows(rows)

    write_atomic(path, writer)


def read_manifest(path: str | Path) -> list[ManifestRow]:
    """Read a manifest CSV; errors name the file and line."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: manifest not found")
    try:
        with open(p, newline="", encoding="utf-8") as f:
            reader = csv.DictReader(f)
            fields = [c.strip() for c in (reader.fieldnames or [])]
            missing = {"image", "label"} - set(fields)
            if missing:
                raise InputError(f"{p}: header must contain image,label "
                                 f"(missing {', '.join(sorted(missing))})")
            rows = []
            for i, raw in enumerate(reader, start=2):
                rec = {(k or "").strip(): (v or "").strip() for k, v in raw.items() if k is not None}
                where = f"{p}:{i}"
                if not rec.get("image"):
                    raise InputError(f"{where}: empty image path")
                if not rec.get("label"):
                    raise InputError(f"{where}: empty label")
                rows.append(ManifestRow(
                    image=(p.parent / rec["image"]), label=rec["label"],
                    az_deg=_opt_float(rec.get("az_deg"), where, "az_deg"),
                    el_deg=_opt_float(rec.get("el_deg"), where, "el_deg"), line=i,
                ))
    except UnicodeDecodeError:
        raise InputError(f"{p}: manifest is not UTF-8 text") from None
    except csv.Error as exc:
        raise InputError(f"{p}: malformed CSV ({exc})") from None
    if not rows:
        raise InputError(f"{p}: manifest has no rows")
    return rows


AUGMENT_ANGLES_DEG = (20.0, 65.0, 110.0, 155.0)
AUGMENT_SCALES = (0.85, 1.0, 1.18)
UNKNOWN_FACTOR = 3.0


def augmented_views(image: np.ndarray) -> list[np.ndarray]:
    """Rotated and zoomed copies of a library image (about its centre, bilinear, edge replicated).

    They stand in for the framing changes a later view of the same case will have, so the
    library can measure its own within-case spread without extra images.
    """
    img = np.asarray(image, dtype=np.float32)
    rows, cols = img.shape
    views = []
    for angle in AUGMENT_ANGLES_DEG:
        for scale in AUGMENT_SCALES:
            m = cv2.getRotationMatrix2D(((cols - 1) / 2.0, (rows - 1) / 2.0), angle, scale)
            views.append(cv2.warpAffine(img, m, (cols, rows), flags=cv2.INTER_LINEAR,
                                        borderMode=cv2.BORDER_REPLICATE))
    return views


@dataclass(frozen=True)
class Spread:
    """Within-case spread of a library, from augmented views of its own images.

    ``deviations``: (m, 7) feature deviations of augmented views from their entry (in feature
    units, unscaled); ``owner``: (m,) index of the entry each deviation belongs to.
    """

    deviations: np.ndarray
    owner: np.ndarray


def feature_scale(spread: Spread, kind: str) -> np.ndarray:
    """Per-feature divisor of the distance.

    ``hu``: 1 (the paper's raw Euclidean distance, Eq. 14). ``log-hu``: the pooled within-case
    RMS deviation of each feature, i.e. a diagonal Mahalanobis distance, so that phi_5..phi_7 of
    near-symmetric spots (log of noise) weigh as little as they deserve. Floored at 1e-5 of the
    largest value so a perfectly stable feature cannot dominate.
    """
    k = spread.deviations.shape[1] if spread.deviations.size else 7
    if kind == "hu" or spread.deviations.shape[0] == 0:
        return np.ones(k)
    rms = np.sqrt(np.mean(spread.deviations**2, axis=0))
    top = float(rms.max())
    if top == 0.0:
        return np.ones(k)
    return np.maximum(rms, 1e-5 * top)


def unknown_thresholds(spread: Spread, scale: np.ndarray, n_entries: int,
                       factor: float = UNKNOWN_FACTOR) -> np.ndarray:
    """Per-entry unknown threshold, shape (n_entries,).

    T_i = ``factor`` x the 95th percentile of the scaled distances between augmented views and
    their entry, taken over the whole library (the augmentation models framing, not sensor
    noise, so one entry's own spread can be unrepresentatively small), and raised to the same
    statistic of entry i's own views where that is larger (shapes sensitive to framing).
    Inf when there is no spread to calibrate from.
    """
    d = np.sqrt(np.sum((spread.deviations / scale) ** 2, axis=1)) if spread.deviations.size else np.empty(0)
    overall = float(factor * np.percentile(d, 95)) if d.size else float("inf")
    out = np.full(n_entries, overall)
    for i in range(n_entries):
        own = d[spread.owner == i]
        if own.size:
            out[i] = max(overall, float(factor * np.percentile(own, 95)))
    return out


def build_library(manifest: str | Path, kind: str = "hu", threshold: float = 0.5,
                  progress: Callable[[int, int], None] | None = None) -> Library:
    """Analyse every manifest image and assemble a :class:`Library` (nothing is written)."""
    if kind not in FEATURE_KINDS:
        raise InputError(f"feature kind must be one of {', '.join(FEATURE_KINDS)}, not {kind!r}")
    rows = read_manifest(manifest)
    entries = []
    deviations, owner = [], []
    for i, row in enumerate(rows):
        try:
            image = read_image(row.image)
            feats = image_features(image, kind, threshold)
        except InputError as exc:
            raise InputError(f"{Path(manifest)}:{row.line}: {exc}") from None
        entries.append(Entry(label=row.label, features=feats, az_deg=row.az_deg, el_deg=row.el_deg,
                             sha256=sha256_file(row.image), image=str(row.image)))
        for view in augmented_views(image):
            try:
                deviations.append(image_features(view, kind, threshold) - feats)
                owner.append(i)
            except InputError:
                continue  # a zoom that pushes the spot out of frame says nothing about the spread
        if progress:
            progress(i + 1, len(rows))
    spread = Spread(np.array(deviations).reshape(-1, 7), np.array(owner, dtype=np.int64))
    lib = Library(features=kind, threshold=float(threshold), entries=entries)
    lib.scale = feature_scale(spread, kind)
    for entry, t in zip(entries, unknown_thresholds(spread, lib.scale, len(entries)), strict=True):
        entry.unknown_distance = float(t)
    lib.unknown_distance = max(e.unknown_distance for e in entries)
    return lib


def library_to_dict(lib: Library) -> dict:
    def entry(e: Entry) -> dict:
        d = {"label": e.label, "features": [float(v) for v in e.features], "az_deg": e.az_deg,
             "el_deg": e.el_deg, "sha256": e.sha256, "image": e.image,
             "unknown_distance": e.unknown_distance if np.isfinite(e.unknown_distance) else None}
        if e.correction is not None:
            d["correction"] = {"az_deg": float(e.correction["az_deg"]),
                               "el_deg": float(e.correction["el_deg"])}
        return d

    return {
        "version": lib.version,
        "features": lib.features,
        "threshold": lib.threshold,
        "normalisation": {"intensity": "unit-mean", "scale": [float(v) for v in lib.scale]},
        "unknown_distance": lib.unknown_distance if np.isfinite(lib.unknown_distance) else None,
        "entries": [entry(e) for e in lib.entries],
    }


def save_library(lib: Library, path: str | Path) -> None:
    """Write the library YAML atomically."""
    text = yaml.safe_dump(library_to_dict(lib), sort_keys=False)
    write_atomic(path, lambda t: t.write_text(text, encoding="utf-8"))


def _vec7(value, where: str) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{where} must be a list of 7 numbers") from None
    if v.shape != (7,) or not np.all(np.isfinite(v)):
        raise InputError(f"{where} must be a list of 7 finite numbers")
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


def load_library(path: str | Path) -> Library:
    """Read and validate a library YAML; errors name the file and key."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: library not found")
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: not readable YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise InputError(f"{p}: library must be a mapping")
    if data.get("version") != LIBRARY_VERSION:
        raise InputError(f"{p}: version: expected {LIBRARY_VERSION}, got {data.get('version')!r}")
    kind = data.get("features")
    if kind not in FEATURE_KINDS:
        raise InputError(f"{p}: features: must be one of {', '.join(FEATURE_KINDS)}, got {kind!r}")
    norm = data.get("normalisation") or {}
    scale = _vec7(norm.get("scale", [1.0] * 7), f"{p}: normalisation.scale")
    if np.any(scale <= 0):
        raise InputError(f"{p}: normalisation.scale must be positive")
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
        entries.append(Entry(label=str(e["label"]), features=_vec7(e.get("features"), f"{where}.features"),
                             az_deg=e.get("az_deg"), el_deg=e.get("el_deg"), sha256=str(e.get("sha256", "")),
                             image=str(e.get("image", "")), correction=corr, unknown_distance=unknown))
    unknown = data.get("unknown_distance")
    try:
        threshold = float(data.get("threshold", 0.5))
    except (TypeError, ValueError):
        raise InputError(f"{p}: threshold: must be a number") from None
    return Library(features=kind, threshold=threshold, entries=entries, scale=scale,
                   unknown_distance=float("inf") if unknown is None else float(unknown))
