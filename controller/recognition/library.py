"""The error library: reference beam images of known error cases, described by Hu features.

Pure: images and labels in, :class:`Library` out (:func:`build_library`); the manifest and
YAML files are handled by :mod:`controller.recognition.library_io`.

Library document (YAML)::

    version: 1
    features: multi-lobe-hu | multi-hu | hu | log-hu | blur-hu | multi-blur-hu   # recognition.features
    threshold: 0.5                 # beam segmentation threshold (hu, log-hu)
    thresholds: [0.1, 0.3, 0.5]    # the descriptor rows: multi-hu k = 7 x 3; multi-lobe-hu
                                   # [0.1, 0.3, 0.5, 0.1] (last row: all lobes) k = 28; blur-hu [0.05] (the
                                   # whole-spot window) k = 6; multi-blur-hu [0.1, 0.3, 0.5, 0.05] k = 27
    normalisation: {intensity: unit-mean, scale: [k numbers], whiten: [[k x k]] (optional)}
    unknown_distance: <float>      # largest per-entry threshold (informative)
    entries:
      - {label, features: [k], az_deg, el_deg, correction: {az_deg, el_deg} (optional), sha256, image,
         unknown_distance, params: {magnitude, heliostat, source, slant_m, ...} (optional)}

Feature kinds:

* ``hu``: phi_1..phi_7 of the segmented spot at unit mean intensity, scale = 1 - the paper's
  raw Euclidean distance.
* ``log-hu``: l_i = -sign(phi_i) log10|phi_i| (|phi_i| floored at 1e-30 so an exact zero
  stays finite), scaled per feature by the standard deviation of the entries' values, so that
  the noisy phi_5..phi_7 of near-symmetric spots do not swamp the distance.
* ``multi-hu``: raw phi_1..phi_7 of the spot segmented at 0.1, 0.3 and 0.5 of its peak (21
  numbers): the halo, shoulders and core of one spot, so an error that only changes the beam's
  wings (a small twist, a short backlash smear) still moves the features. By default the library
  is *whitened* (``normalisation.whiten``, W = C^-1/2 of its own spread, see
  :func:`whitening`), and the distance stays Euclidean in the whitened space.
* ``multi-lobe-hu`` (default of ``heliocal library build``): the multi-hu stack and, as a fourth
  row, Hu of all lobes above 0.1 of the peak (:mod:`controller.recognition.lobes`), so detached
  lobes (a mis-canted facet, facets canted apart) count. Whitened by default.
* ``blur-hu``: six features invariant to a circularly symmetric blur, to zoom and brightness,
  from Hu's phi_2..phi_7 of the whole (unthresholded) spot signal
  (:mod:`controller.imaging.blur_moments`, :mod:`controller.recognition.blur_features`);
  ``multi-blur-hu``: the multi-hu stack and these side by side (27). Both whitened by default.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from controller.errors import InputError
from controller.imaging.beam import analyze
from controller.recognition.estimate import estimate
from controller.recognition.features import (
    FEATURE_KINDS,
    MULTI_THRESHOLDS,
    describe,
    hu_features,
    hu_stack,
    image_features,
    kind_thresholds,
)
from controller.recognition.matching import Matcher
from controller.recognition.segments import magnitude_segments

LIBRARY_VERSION = 1


@dataclass(frozen=True)
class LibraryMatch:
    """The library's answer for one beam: nearest case and distance, the nearest other case,
    whether it is too far to trust (``unknown``), and the entry's az/el correction (deg).

    Magnitude (:mod:`controller.recognition.estimate`): ``error_deg`` is the beam's pointing
    error (Δaz, Δel) in degrees interpolated over the nearest entries of the matched case that
    carry ``az_deg``/``el_deg`` (None when unknown or none do); ``coarse_correction_deg`` =
    −``error_deg``, the move that undoes it; ``magnitude`` likewise from the entries'
    ``params.magnitude``; ``confidence`` in [0, 1] (0 when unknown)."""

    label: str
    distance: float
    index: int
    runner_up: str | None
    runner_up_distance: float | None
    unknown: bool
    correction_deg: tuple[float, float] | None
    error_deg: tuple[float, float] | None = None
    coarse_correction_deg: tuple[float, float] | None = None
    magnitude: float | None = None
    confidence: float = 0.0


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
    params: dict | None = None  # the error state it shows: magnitude, heliostat, source, slant_m, ...


@dataclass
class Library:
    features: str
    threshold: float
    entries: list[Entry]
    scale: np.ndarray = field(default_factory=lambda: np.ones(7))
    unknown_distance: float = float("inf")
    version: int = LIBRARY_VERSION
    whiten: np.ndarray | None = None  # (k, k): features are compared as W f (then scale is 1)
    interpolate: bool = True  # match along segments between neighbouring magnitudes of a case
    _cache: tuple[int, Matcher] | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def labels(self) -> list[str]:
        return [e.label for e in self.entries]

    @property
    def thresholds(self) -> tuple[float, ...]:
        """Segmentation thresholds of the features (one Hu vector each)."""
        return kind_thresholds(self.features, self.threshold)

    def matrix(self) -> np.ndarray:
        """(n, k) entry features as stored (before whitening/scaling)."""
        k = len(self.entries[0].features) if self.entries else 7
        return np.array([e.features for e in self.entries], dtype=np.float64).reshape(-1, k)

    def transform(self, features: np.ndarray) -> np.ndarray:
        """Stored features (..., k) -> the space the Euclidean distance is taken in."""
        f = np.asarray(features, dtype=np.float64)
        return f @ self.whiten.T if self.whiten is not None else f / self.scale

    def matcher(self) -> Matcher:
        x = self.transform(self.matrix())
        limits = np.array([e.unknown_distance for e in self.entries], dtype=np.float64)
        segments = magnitude_segments(self.entries, x) if self.interpolate else None
        return Matcher(x, self.labels, None, limits, segments=segments)

    def describe(self, hdr: np.ndarray, threshold: float | None = None) -> np.ndarray:
        """The descriptor stack of a beam image, shape (len(thresholds), 7): Hu moments at the
        library's thresholds, and for a blur kind the whole-spot blur-invariant Hu as the last
        row (:func:`controller.recognition.features.describe`; background auto; ``threshold``
        overrides a single-threshold library's)."""
        if threshold is None or self.features not in ("hu", "log-hu"):
            return describe(hdr, self.features, self.threshold)
        return hu_stack(hdr, (threshold,))

    def match_hu(self, hu: np.ndarray) -> LibraryMatch:
        """The nearest entry to a beam's Hu moments and the nearest of another case (Euclidean
        distance of the library's features, Eq. 14), with that entry's correction and the
        interpolated magnitude estimate. ``hu``: (7,) at the library's threshold, or the
        (len(thresholds), 7) stack of :meth:`describe` (required by ``multi-hu``)."""
        h = np.asarray(hu, dtype=np.float64)
        if h.size != 7 * len(self.thresholds):
            raise InputError(f"a {self.features} library needs Hu moments at thresholds "
                             f"{list(self.thresholds)} ({7 * len(self.thresholds)} numbers, got {h.size}); "
                             "use Library.describe(image)")
        q = self.transform(hu_features(h.reshape(-1), self.features))
        matcher = self._matcher()
        m = matcher.match(q)
        corr = self.entries[m.index].correction
        est = estimate(self, matcher, q, m)
        return LibraryMatch(m.label, m.distance, m.index, m.runner_up_label, m.runner_up_distance, m.unknown,
                            (float(corr["az_deg"]), float(corr["el_deg"])) if corr else None,
                            est.error_deg, est.coarse_correction_deg, est.magnitude, est.confidence)

    def match_image(self, hdr: np.ndarray, *, threshold: float | None = None) -> LibraryMatch:
        """:meth:`match_hu` of a beam image (2-D HDR or grey, x = column, y = row), segmented at
        the library's threshold(s) (``threshold``, a fraction of the peak, overrides a
        single-threshold library's) with the background estimated
        (:func:`controller.imaging.beam.analyze`). InputError when there is no beam."""
        return self.match_hu(self.describe(hdr, threshold))

    def _matcher(self) -> Matcher:
        # Built once per library: the matcher precomputes its search arrays.
        if self._cache is None or self._cache[0] != len(self.entries):
            self._cache = (len(self.entries), self.matcher())
        return self._cache[1]


AUGMENT_ANGLES_DEG = (20.0, 65.0, 110.0, 155.0)
AUGMENT_SCALES = (0.85, 1.0, 1.18)
UNKNOWN_FACTOR = 3.0
AUGMENT_BLUR = (0.05, 0.1, 0.2)  # Gaussian blur sigma as a fraction of the spot's d90 (spot size)


def augmented_views(image: np.ndarray, blur: bool = False) -> list[np.ndarray]:
    """Rotated and zoomed copies of a library image (about its centre, bilinear, edge replicated)
    and, with ``blur``, Gaussian-blurred copies (σ = 0.05, 0.1, 0.2 × the spot's d90 at the
    lowest threshold).

    They stand in for the framing changes a later view of the same case will have, so the
    library can measure its own within-case spread without extra images. The blurred copies
    stand in for a larger spot (a larger source disc or a softer focus convolves the spot with a
    wider kernel): whitening then gives the direction in which spot size moves the features
    the weight of a nuisance, not of a case difference.
    """
    img = np.asarray(image, dtype=np.float32)
    rows, cols = img.shape
    views = []
    for angle in AUGMENT_ANGLES_DEG:
        for scale in AUGMENT_SCALES:
            m = cv2.getRotationMatrix2D(((cols - 1) / 2.0, (rows - 1) / 2.0), angle, scale)
            views.append(cv2.warpAffine(img, m, (cols, rows), flags=cv2.INTER_LINEAR,
                                        borderMode=cv2.BORDER_REPLICATE))
    if blur:
        d90 = analyze(img, threshold=MULTI_THRESHOLDS[0], background="auto").d90_px
        for f in AUGMENT_BLUR:
            views.append(cv2.GaussianBlur(img, (0, 0), sigmaX=max(f * d90, 0.3),
                                          borderType=cv2.BORDER_REPLICATE))
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


def whitening(x: np.ndarray, spread: Spread, floor: float = 1e-6) -> np.ndarray:
    """ZCA whitening W = C^(-1/2) (k, k) learned from the library's own *within-case* spread.

    C = second moment of the augmented views' deviations from their entry (framing, zoom, blur:
    the nuisances a later view of the same case will have), i.e. a Mahalanobis distance whose
    covariance is the nuisance alone, as in Fisher's discriminant: directions the nuisances
    hardly move (where the cases differ) keep their weight, directions they move a lot (spot
    size, noise of phi_5..phi_7) are shrunk. Adding the covariance of the entries themselves
    (how the cases differ) shrank exactly the directions that separate them: on the independent
    sets of docs/recognition.md that cost 3-13 points. Without deviations, C = covariance of
    the entries ``x`` (n, k). Eigenvalues are floored at ``floor`` x the largest, so a direction
    in which nothing varies is not blown up beyond 1/sqrt(floor). The distance is still the
    Euclidean distance of Eq. 14, on W f.
    """
    x = np.asarray(x, dtype=np.float64)
    k = x.shape[1]
    if spread.deviations.size:
        c = spread.deviations.T @ spread.deviations / spread.deviations.shape[0]
    else:
        c = np.cov(x.T, bias=True).reshape(k, k) if x.shape[0] > 1 else np.zeros((k, k))
    w, v = np.linalg.eigh(c)
    if not w.max() > 0:
        return np.eye(k)
    w = np.maximum(w, floor * w.max())
    return (v / np.sqrt(w)) @ v.T


def neighbour_thresholds(x: np.ndarray, labels: Sequence[str]) -> np.ndarray:
    """Per entry, the distance (in the matching space) to the nearest other entry of the same case
    (inf when it has none): a view of a magnitude between two library magnitudes lies about
    that far from the nearer one, and must not be rejected as unknown."""
    lab = np.asarray(labels)
    out = np.full(len(lab), np.inf)
    for i in range(len(lab)):
        same = (lab == lab[i]) & (np.arange(len(lab)) != i)
        if same.any():
            out[i] = float(np.min(np.linalg.norm(x[same] - x[i], axis=1)))
    return out


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
                  names: Sequence[str] | None = None, params: Sequence[dict | None] | None = None,
                  whiten: bool | None = None,
                  progress: Callable[[int, int], None] | None = None) -> Library:
    """A :class:`Library` from beam images and their case labels (nothing is read or written).

    Each image gives one entry (its features); rotated and zoomed copies of it, and blurred
    ones for a whitened library (:func:`augmented_views`), measure the within-case spread that
    sets the feature scale and every entry's unknown threshold. ``az_deg``/``el_deg``,
    ``sha256`` and ``names`` (image file names) and ``params`` (the error state each image
    shows) are carried into the entries.
    ``whiten`` (default: all kinds but ``hu`` and ``log-hu``) compares features after :func:`whitening`.
    Unknown thresholds: :func:`unknown_thresholds`, raised to :func:`neighbour_thresholds`.
    An image without a beam raises InputError naming its position (or name).
    """
    if kind not in FEATURE_KINDS:
        raise InputError(f"feature kind must be one of {', '.join(FEATURE_KINDS)}, not {kind!r}")
    n = len(images)
    if n == 0 or len(labels) != n:
        raise InputError(f"a library needs one label per image and at least one image ({n} images, "
                         f"{len(labels)} labels)")
    whitened = kind not in ("hu", "log-hu") if whiten is None else whiten
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
                             image=names[i] if names is not None else "",
                             params=dict(params[i]) if params is not None and params[i] else None))
        for view in augmented_views(image, blur=whitened):
            try:
                deviations.append(image_features(view, kind, threshold) - feats)
                owner.append(i)
            except InputError:
                continue  # a zoom that pushes the spot out of frame says nothing about the spread
        if progress:
            progress(i + 1, n)
    k = len(entries[0].features)
    spread = Spread(np.array(deviations).reshape(-1, k), np.array(owner, dtype=np.int64))
    lib = Library(features=kind, threshold=float(threshold), entries=entries, scale=np.ones(k))
    if whitened:
        lib.whiten = whitening(lib.matrix(), spread)
    else:
        lib.scale = feature_scale(spread, kind)
    # The transform is linear: deviations map into the matching space as they are.
    own = unknown_thresholds(Spread(lib.transform(spread.deviations), spread.owner), np.ones(k), len(entries))
    near = neighbour_thresholds(lib.transform(lib.matrix()), lib.labels)
    for entry, t, t_nb in zip(entries, own, near, strict=True):
        entry.unknown_distance = float(max(t, t_nb) if np.isfinite(t_nb) else t)
    lib.unknown_distance = max(e.unknown_distance for e in entries)
    return lib
