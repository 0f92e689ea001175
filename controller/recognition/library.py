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
    widen: [0.1, 0.2]              # σ/d90 of widened copies tried on an unknown view (optional)
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
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from controller.errors import InputError
from controller.recognition.estimate import estimate
from controller.recognition.features import (
    FEATURE_KINDS,
    describe,
    hu_features,
    hu_stack,
    image_features,
    kind_thresholds,
)
from controller.recognition.matching import Matcher
from controller.recognition.segments import magnitude_segments
from controller.recognition.spread import (
    Spread,
    feature_scale,
    neighbour_thresholds,
    unknown_thresholds,
    whitening,
)
from controller.recognition.widen import WIDEN, WIDEN_ACCEPT, spot_d90, widened

LIBRARY_VERSION = 1


@dataclass(frozen=True)
class Match:
    """The library's answer for one beam — the one match type of the product (the cycle, the
    CLI, the reports): nearest case and distance, the nearest other case, whether it is too
    far to trust (``unknown``), the entry's az/el correction (deg) and the library entry
    (``index``; -1 when not from a library).

    Magnitude (:mod:`controller.recognition.estimate`): ``error_deg`` is the beam's pointing
    error (Δaz, Δel) in degrees interpolated over the nearest entries of the matched case that
    carry ``az_deg``/``el_deg`` (None when unknown or none do); ``coarse_correction_deg`` =
    −``error_deg``, the move that undoes it; ``magnitude`` likewise from the entries'
    ``params.magnitude``; ``confidence`` in [0, 1] (0 when unknown).

    ``widened``: 0 for a direct match; else the Gaussian σ (× the spot's d90) that widened a
    view no case claimed before one did (:mod:`controller.recognition.widen`). Such a match
    names the case but not its size (the widened spot shows a smaller relative magnitude):
    ``error_deg``, ``coarse_correction_deg`` and ``magnitude`` are None, ``confidence`` 0."""

    label: str
    distance: float
    runner_up: str | None = None
    runner_up_distance: float | None = None
    unknown: bool = False
    correction_deg: tuple[float, float] | None = None
    index: int = -1
    error_deg: tuple[float, float] | None = None
    coarse_correction_deg: tuple[float, float] | None = None
    magnitude: float | None = None
    confidence: float = 0.0
    widened: float = 0.0


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
    widen: tuple[float, ...] = ()  # σ / d90 of the widened copies tried on an unknown view (widen.WIDEN)
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

    def match_hu(self, hu: np.ndarray) -> Match:
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
        return Match(m.label, m.distance, m.runner_up_label, m.runner_up_distance, m.unknown,
                     (float(corr["az_deg"]), float(corr["el_deg"])) if corr else None, m.index,
                     est.error_deg, est.coarse_correction_deg, est.magnitude, est.confidence)

    def descriptors(self, hdr: np.ndarray, threshold: float | None = None) -> list[np.ndarray]:
        """The descriptor stack of a beam image (:meth:`describe`) and, when no case claims it
        and the library has ``widen``, the stacks of its widened copies in that order
        (:func:`controller.recognition.widen.widened`); :meth:`match_stacks` takes the list."""
        stacks = [self.describe(hdr, threshold)]
        if self.widen and self.match_hu(stacks[0]).unknown:
            stacks += self._widened_stacks(hdr, threshold)
        return stacks

    def match_stacks(self, stacks: Sequence[np.ndarray]) -> Match:
        """The direct match of ``stacks[0]`` unless it is unknown; then the first widened
        stack (``stacks[i]`` widened by ``widen[i - 1]``) within :data:`WIDEN_ACCEPT` × its
        entry's unknown threshold, as a case without a size or correction
        (:class:`Match`); if none is, the direct (unknown) match."""
        return self._widened_match(self.match_hu(stacks[0]), stacks[1:])

    def match_image(self, hdr: np.ndarray, *, threshold: float | None = None) -> Match:
        """:meth:`match_stacks` of a beam image (2-D HDR or grey, x = column, y = row), segmented
        at the library's threshold(s) (``threshold``, a fraction of the peak, overrides a
        single-threshold library's) with the background estimated
        (:func:`controller.imaging.beam.analyze`), widened if no case claims it
        (:meth:`descriptors`). InputError when there is no beam."""
        direct = self.match_hu(self.describe(hdr, threshold))
        if not direct.unknown or not self.widen:
            return direct
        return self._widened_match(direct, self._widened_stacks(hdr, threshold))

    def _widened_stacks(self, hdr: np.ndarray, threshold: float | None) -> list[np.ndarray]:
        d90 = spot_d90(hdr)
        return [self.describe(widened(hdr, f, d90), threshold) for f in self.widen]

    def _widened_match(self, direct: Match, stacks: Sequence[np.ndarray]) -> Match:
        if not direct.unknown:
            return direct
        for fraction, stack in zip(self.widen, stacks, strict=False):
            m = self.match_hu(stack)
            if m.distance <= WIDEN_ACCEPT * self.entries[m.index].unknown_distance:
                return replace(m, correction_deg=None, error_deg=None, coarse_correction_deg=None,
                               magnitude=None, confidence=0.0, widened=float(fraction))
        return direct

    def _matcher(self) -> Matcher:
        # Built once per library: the matcher precomputes its search arrays.
        if self._cache is None or self._cache[0] != len(self.entries):
            self._cache = (len(self.entries), self.matcher())
        return self._cache[1]


AUGMENT_ANGLES_DEG = (20.0, 65.0, 110.0, 155.0)
AUGMENT_SCALES = (0.85, 1.0, 1.18)
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
        d90 = spot_d90(img)
        views += [widened(img, f, d90) for f in AUGMENT_BLUR]
    return views


def build_library(images: Sequence[np.ndarray], labels: Sequence[str], *, kind: str = "hu",
                  threshold: float = 0.5, az_deg: Sequence[float | None] | None = None,
                  el_deg: Sequence[float | None] | None = None, sha256: Sequence[str] | None = None,
                  names: Sequence[str] | None = None, params: Sequence[dict | None] | None = None,
                  whiten: bool | None = None, widen: Sequence[float] | None = None,
                  progress: Callable[[int, int], None] | None = None) -> Library:
    """A :class:`Library` from beam images and their case labels (nothing is read or written).

    Each image gives one entry (its features); rotated and zoomed copies of it, and blurred
    ones for a whitened library (:func:`augmented_views`), measure the within-case spread that
    sets the feature scale and every entry's unknown threshold. ``az_deg``/``el_deg``,
    ``sha256`` and ``names`` (image file names) and ``params`` (the error state each image
    shows) are carried into the entries.
    ``whiten`` (default: all kinds but ``hu`` and ``log-hu``) compares features after :func:`whitening`.
    ``widen`` (default: :data:`~controller.recognition.widen.WIDEN` for a whitened library, whose
    blurred views taught it how a larger spot moves the features; none otherwise, so the paper's
    raw ``hu`` stays the paper's) is stored as :attr:`Library.widen`.
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
    lib = Library(features=kind, threshold=float(threshold), entries=entries, scale=np.ones(k),
                  widen=tuple(float(f) for f in (widen if widen is not None else WIDEN if whitened else ())))
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
