"""The error library: reference beam images of known error cases, described by Hu features.

Pure: images and labels in, :class:`Library` out (:func:`build_library`); the manifest and
YAML files are handled by :mod:`controller.recognition.library_io`.

Library document (YAML)::

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

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from controller.errors import InputError
from controller.imaging.beam import analyze
from controller.recognition.matching import Matcher

LIBRARY_VERSION = 1
FEATURE_KINDS = ("hu", "log-hu")
_LOG_FLOOR = 1e-30


@dataclass(frozen=True)
class LibraryMatch:
    """The library's answer for one beam: nearest case and distance, the nearest other case,
    whether it is too far to trust (``unknown``), and the entry's az/el correction (deg)."""

    label: str
    distance: float
    index: int
    runner_up: str | None
    runner_up_distance: float | None
    unknown: bool
    correction_deg: tuple[float, float] | None


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
    _cache: tuple[int, Matcher] | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def labels(self) -> list[str]:
        return [e.label for e in self.entries]

    def matrix(self) -> np.ndarray:
        return np.array([e.features for e in self.entries], dtype=np.float64).reshape(-1, 7)

    def matcher(self) -> Matcher:
        return Matcher(self.matrix(), self.labels, self.scale,
                       np.array([e.unknown_distance for e in self.entries], dtype=np.float64))

    def match_hu(self, hu: np.ndarray) -> LibraryMatch:
        """The nearest entry to a beam's Hu moments (7,) and the nearest of another case
        (Euclidean distance of the library's features, Eq. 14), with that entry's correction."""
        m = self._matcher().match(hu_features(hu, self.features))
        corr = self.entries[m.index].correction
        return LibraryMatch(m.label, m.distance, m.index, m.runner_up_label, m.runner_up_distance, m.unknown,
                            (float(corr["az_deg"]), float(corr["el_deg"])) if corr else None)

    def match_image(self, hdr: np.ndarray, *, threshold: float | None = None) -> LibraryMatch:
        """:meth:`match_hu` of a beam image (2-D HDR or grey, x = column, y = row), segmented at
        the library's threshold (or ``threshold``, a fraction of the peak) with the background
        estimated (:func:`controller.imaging.beam.analyze`). InputError when there is no beam."""
        t = self.threshold if threshold is None else threshold
        return self.match_hu(analyze(hdr, threshold=t, background="auto").hu)

    def _matcher(self) -> Matcher:
        # Built once per library: the matcher precomputes its search arrays.
        if self._cache is None or self._cache[0] != len(self.entries):
            self._cache = (len(self.entries), self.matcher())
        return self._cache[1]


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


def build_library(images: Sequence[np.ndarray], labels: Sequence[str], *, kind: str = "hu",
                  threshold: float = 0.5, az_deg: Sequence[float | None] | None = None,
                  el_deg: Sequence[float | None] | None = None, sha256: Sequence[str] | None = None,
                  names: Sequence[str] | None = None,
                  progress: Callable[[int, int], None] | None = None) -> Library:
    """A :class:`Library` from beam images and their case labels (nothing is read or written).

    Each image gives one entry (its features); rotated and zoomed copies of it
    (:func:`augmented_views`) measure the within-case spread that sets the feature scale and
    every entry's unknown threshold. ``az_deg``/``el_deg``, ``sha256`` and ``names`` (image
    file names) are carried into the entries. An image without a beam raises InputError
    naming its position (or name).
    """
    if kind not in FEATURE_KINDS:
        raise InputError(f"feature kind must be one of {', '.join(FEATURE_KINDS)}, not {kind!r}")
    n = len(images)
    if n == 0 or len(labels) != n:
        raise InputError(f"a library needs one label per image and at least one image ({n} images, "
                         f"{len(labels)} labels)")
    entries = []
    deviations, owner = [], []
    for i, (image, label) in enumerate(zip(images, labels, strict=True)):
        name = names[i] if names is not None else f"image {i}"
        try:
            feats = image_features(image, kind, threshold)
        except InputError as exc:
            raise InputError(f"{name}: {exc}") from None
        entries.append(Entry(label=str(label), features=feats, az_deg=az_deg[i] if az_deg else None,
                             el_deg=el_deg[i] if el_deg else None, sha256=sha256[i] if sha256 else "",
                             image=names[i] if names is not None else ""))
        for view in augmented_views(image):
            try:
                deviations.append(image_features(view, kind, threshold) - feats)
                owner.append(i)
            except InputError:
                continue  # a zoom that pushes the spot out of frame says nothing about the spread
        if progress:
            progress(i + 1, n)
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
