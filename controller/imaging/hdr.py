"""HDR merge of a double-CCD pair with a known response (HDR paper Eq. (1)).

For every pixel j, with sensor k's value ``z_k``, exposure ``t_k``, inverse response
``I_k = f_k⁻¹(z_k)`` and weight ``w_k = w(z_k)``::

    x_j = (w_1 t_1 I_1 + w_2 t_2 I_2) / (w_1 t_1² + w_2 t_2²)              (1)

``x_j`` is in exposure-value units per second (irradiance; with the linear default CRF,
counts per second). Eq. (1) is the Robertson et al. estimator for a known response.

Pixels no weight covers (total weight 0) get a finite value and are flagged:

* **saturated in both** (the HIGH value is in its upper half): ``x = I_1(z_1) / t_1``, the lower
  bound from the shorter exposure (the largest bound the pair gives);
* **dark in both** (otherwise): ``x = I_2(z_2) / t_2``, the upper bound from the longer
  exposure (the smallest bound; 0 when a fitted CRF puts ``I = 0`` at the dark offset).

One consistency rule overrides Eq. (1): when the HIGH value is at or below the dark offset,
the pixel is **dark in both** whatever LOW reads. LOW collects only ``t_1 / t_2`` of HIGH's
light, so a LOW signal over a dark HIGH pixel is noise; Eq. (1) would return it as
``I_1 / t_1`` because ``w_2 = 0`` there (the raised-cosine, noise-optimal, Mitsunaga and
Reinhard weights vanish at or below the offset, or close to it).

For 8-bit sensors the result depends only on ``(z_1, z_2)``, so :class:`HdrMerger` builds a
65,536-entry table once per (exposures, CRF, weighting) and a merge is one gather.

References
----------
.. [1] The HDR paper, Eq. (1).
.. [2] Robertson, M. A., Borman, S., Stevenson, R. L., J. Electron. Imaging 12 (2003) 219.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controller.errors import InputError
from controller.imaging import weights as W
from controller.imaging.crf import Crf

VALID, SATURATED_BOTH, DARK_BOTH = 0, 1, 2


def merge_pair(z_low: np.ndarray, z_high: np.ndarray, exposures: tuple[float, float],
               inverse_low: np.ndarray, inverse_high: np.ndarray, weights_low: np.ndarray,
               weights_high: np.ndarray, dark_offset: float = 8.0) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (1) in float64 for integer pixel arrays, with the documented rules for uncovered
    pixels and for a dark HIGH pixel (module docstring).

    Parameters
    ----------
    z_low, z_high : integer arrays of equal shape, pixel values of the LOW (short) and HIGH
        (long) exposure.
    exposures : (t_1, t_2) in seconds, t_1 <= t_2.
    inverse_low, inverse_high : I_k(z) tables, shape (2**N,).
    weights_low, weights_high : w_k(z) tables, shape (2**N,).
    dark_offset : counts; HIGH values at or below it make the pixel dark in both.

    Returns
    -------
    (x, code): x float64 merged irradiance; code uint8, 0 valid, 1 saturated in both,
    2 dark in both.
    """
    t1, t2 = float(exposures[0]), float(exposures[1])
    i1, i2 = inverse_low[z_low], inverse_high[z_high]
    w1, w2 = weights_low[z_low], weights_high[z_high]
    den = w1 * t1 * t1 + w2 * t2 * t2
    covered = den > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(covered, (w1 * t1 * i1 + w2 * t2 * i2) / np.where(covered, den, 1.0), 0.0)
    mid = (inverse_high.size - 1) / 2.0
    sat = ~covered & (z_high > mid)
    dark = (~covered & ~sat) | (z_high <= dark_offset)
    x = np.where(sat, i1 / t1, np.where(dark, i2 / t2, x))
    code = np.where(sat, SATURATED_BOTH, np.where(dark, DARK_BOTH, VALID)).astype(np.uint8)
    return x, code


@dataclass(frozen=True)
class MergeResult:
    """A merged image with its validity: ``hdr`` float32 (rows, cols); ``valid`` bool, False
    where no weight covers the pixel; counts of the two uncovered classes."""

    hdr: np.ndarray
    valid: np.ndarray
    saturated_both: int
    dark_both: int


def pair_bit_depth(low: np.ndarray, high: np.ndarray, crf: Crf | None = None) -> int:
    """Sensor bit depth for merging ``low`` and ``high`` (integer pixel arrays).

    The CRF's when there is one; 8 when both arrays are 8-bit (or not integer, which the merge
    rejects); otherwise the smallest depth (at least 8) that holds the largest pixel value,
    since 10-, 12- and 14-bit sensors are stored in 16-bit containers and the merge's tables
    must span only the sensor's range.
    """
    if crf is not None:
        return crf.bit_depth
    integer = np.issubdtype(low.dtype, np.integer) and np.issubdtype(high.dtype, np.integer)
    if not integer or (low.dtype.itemsize == 1 and high.dtype.itemsize == 1) or not (low.size and high.size):
        return 8
    return max(8, max(int(low.max()), int(high.max()), 1).bit_length())


class HdrMerger:
    """Merge LOW/HIGH pairs by Eq. (1) with a precomputed (z_1, z_2) table.

    Parameters
    ----------
    exposures : (t_low, t_high) seconds, t_low <= t_high.
    crf : inverse responses (None: linear ``I(z) = z`` for both sensors).
    weighting : one of :data:`controller.imaging.weights.NAMES`.
    dark_offset : dark-signal offset in counts (raised-cosine low side, noise-optimal).
    bit_depth : sensor bits (default: the CRF's, else 8). Above 8 bits the table would be too
        large, and the merge evaluates Eq. (1) per pixel from per-sensor tables instead.
    read_noise, full_well : noise model of ``noise-optimal`` (counts RMS; electrons, with the
        full well filling ``2**N - 1 - dark_offset`` counts). ``electrons_per_count``
        overrides the full-well value (e.g. from :func:`estimate_noise_model`).
    deneve_a, deneve_b : constants of the ``deneve`` weight.
    """

    def __init__(self, exposures: tuple[float, float] = (0.010, 0.020), crf: Crf | None = None,
                 weighting: str = "raised-cosine", dark_offset: float = 8.0, *,
                 bit_depth: int | None = None, read_noise: float = 0.8, full_well: float = 20000.0,
                 electrons_per_count: float | None = None, deneve_a: float = 1.0,
                 deneve_b: float = 1.0) -> None:
        t1, t2 = (float(t) for t in exposures)
        if not (np.isfinite(t1) and np.isfinite(t2)) or t1 <= 0 or t2 <= 0:
            raise InputError(f"exposures must be positive seconds, got {exposures}")
        if t1 > t2:
            raise InputError(f"exposures must be (LOW, HIGH) with LOW <= HIGH, got {exposures}")
        if weighting not in W.NAMES:
            raise InputError(f"unknown weighting {weighting!r} (choose from {', '.join(W.NAMES)})")
        bits = bit_depth if bit_depth is not None else (crf.bit_depth if crf is not None else 8)
        if crf is not None and crf.bit_depth != bits:
            raise InputError(f"CRF is for {crf.bit_depth}-bit sensors, merger set to {bits} bits")
        z_max = (1 << bits) - 1
        if not 0 <= dark_offset < z_max / 2:
            raise InputError(f"dark offset must be in [0, {z_max / 2}), got {dark_offset}")
        self.exposures = (t1, t2)
        self.weighting = weighting
        self.bit_depth = bits
        self.dark_offset = float(dark_offset)
        levels = np.arange(z_max + 1, dtype=float)
        self.inverse = tuple(levels if crf is None else crf.inverse(k) for k in (0, 1))
        epc = electrons_per_count if electrons_per_count is not None else full_well / (z_max - dark_offset)
        self.weights = tuple(
            W.weight_table(weighting, bit_depth=bits, dark_offset=dark_offset, inverse_response=inv,
                           read_noise=read_noise, electrons_per_count=epc, deneve_a=deneve_a,
                           deneve_b=deneve_b)
            for inv in self.inverse)
        self._table: np.ndarray | None = None
        self._codes: np.ndarray | None = None
        if bits <= 8:
            z1, z2 = np.meshgrid(np.arange(z_max + 1), np.arange(z_max + 1), indexing="ij")
            x, code = merge_pair(z1, z2, self.exposures, *self.inverse, *self.weights, self.dark_offset)
            # Index = z1 << bits | z2, flattened once so that a merge is a single gather.
            self._table = x.astype(np.float32).ravel()
            self._codes = code.ravel()

    @classmethod
    def from_camera_config(cls, camera_cfg, crf: Crf | None = None, weighting: str = "raised-cosine",
                           exposures: tuple[float, float] | None = None) -> HdrMerger:
        """From a :class:`controller.config.Camera` (dark offset, bit depth, noise, full well) and
        the camera's response ``crf`` (None: linear; the caller reads ``crf_file``);
        ``exposures`` (s, LOW first) default to the configured ones."""
        if exposures is None:
            exposures = (camera_cfg.sensors[0].exposure_s, camera_cfg.sensors[1].exposure_s)
        return cls(tuple(exposures), crf, weighting,
                   camera_cfg.dark_offset_counts, bit_depth=camera_cfg.bit_depth,
                   read_noise=camera_cfg.read_noise_counts, full_well=camera_cfg.full_well_electrons)

    def _check(self, low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        low = np.asarray(low)
        high = np.asarray(high)
        if low.ndim != 2 or high.ndim != 2:
            raise InputError(f"LOW and HIGH must be 2-D images, got shapes {low.shape} and {high.shape}")
        if low.shape != high.shape:
            raise InputError(f"LOW and HIGH differ in size: {low.shape} vs {high.shape}")
        z_max = (1 << self.bit_depth) - 1
        want = np.uint8 if self.bit_depth <= 8 else np.uint16
        out = []
        for name, img in (("LOW", low), ("HIGH", high)):
            if img.dtype != want:
                if not np.issubdtype(img.dtype, np.integer):
                    raise InputError(f"{name} must hold integer pixel values, got {img.dtype}")
                if img.size and (img.min() < 0 or img.max() > z_max):
                    raise InputError(f"{name} has pixel values outside 0..{z_max} "
                                     f"(max {img.max()}) for a {self.bit_depth}-bit merge")
                img = img.astype(want)
            elif np.iinfo(want).max > z_max and img.size and img.max() > z_max:  # e.g. 12 bits in uint16
                raise InputError(f"{name} has pixel values above {z_max} for a {self.bit_depth}-bit merge")
            out.append(img)
        return out[0], out[1]

    def _index(self, low: np.ndarray, high: np.ndarray) -> np.ndarray:
        idx = low.astype(np.uint16)
        idx <<= self.bit_depth
        idx |= high
        return idx

    def merge(self, low: np.ndarray, high: np.ndarray) -> np.ndarray:
        """Merge one pair: 2-D integer arrays of equal shape -> 2-D float32 ``x_j`` (Eq. (1))."""
        low, high = self._check(low, high)
        if self._table is None:
            x, _ = merge_pair(low, high, self.exposures, *self.inverse, *self.weights, self.dark_offset)
            return x.astype(np.float32)
        # np.take with mode="clip" skips the bounds check (the index cannot exceed the table)
        # and, unlike fancy indexing, gathers straight from the uint16 index: ~4x faster.
        return np.take(self._table, self._index(low, high), mode="clip")

    def merge_with_mask(self, low: np.ndarray, high: np.ndarray) -> MergeResult:
        """Merge and flag uncovered pixels (see the module docstring for their values)."""
        low, high = self._check(low, high)
        if self._table is None:
            x, code = merge_pair(low, high, self.exposures, *self.inverse, *self.weights, self.dark_offset)
            hdr = x.astype(np.float32)
        else:
            idx = self._index(low, high)
            hdr = np.take(self._table, idx, mode="clip")
            code = np.take(self._codes, idx, mode="clip")
        return MergeResult(hdr, code == VALID, int(np.count_nonzero(code == SATURATED_BOTH)),
                           int(np.count_nonzero(code == DARK_BOTH)))


def merge_above_offset(low: np.ndarray, high: np.ndarray, exposures: tuple[float, float],
                       dark_offset: float = 8.0, weighting: str = "raised-cosine") -> np.ndarray:
    """Merged irradiance of an 8-bit pair above the dark offset, counts per second (float64).

    With the linear response ``I(z) = z`` Eq. (1) and its rules for uncovered pixels are linear
    in ``I``, so the offset's share of a pixel is the same merge with ``I(z) = 1``
    (``Σ w t / Σ w t²``, or ``1/t`` where one exposure is used), times the offset::

        x_j - o · x_j[I = 1],   o = ``dark_offset`` (counts)

    This removes the offset without a fitted CRF (whose ``I`` is 0 at the offset), e.g. for
    flux maps whose scale comes from a sun image taken by the same camera.
    """
    merger = HdrMerger(exposures, None, weighting, dark_offset)
    merged = np.asarray(merger.merge(low, high), dtype=np.float64)  # validates the pair
    ones = np.ones_like(merger.inverse[0])
    share, _ = merge_pair(low.astype(np.intp), high.astype(np.intp), merger.exposures, ones, ones,
                          *merger.weights, merger.dark_offset)
    return merged - merger.dark_offset * share


def estimate_noise_model(frames: np.ndarray, dark_offset: float) -> tuple[float, float]:
    """Estimate (read_noise counts, electrons_per_count) from repeated frames of a still scene.

    ``frames``: shape (n_frames, rows, cols), one sensor. Per pixel, mean m and variance v are
    fitted by the photon-transfer line ``v = r² + 1/12 + (m - a) / k`` (least squares over
    unsaturated pixels), giving the inputs of the ``noise-optimal`` weight.

    References
    ----------
    Janesick, "Photon Transfer", SPIE Press, 2007, ch. 2.
    """
    f = np.asarray(frames, dtype=float)
    if f.ndim != 3 or f.shape[0] < 2:
        raise InputError("noise estimation needs at least 2 frames of shape (rows, cols)")
    z_max = float(np.iinfo(frames.dtype).max) if np.issubdtype(frames.dtype, np.integer) else f.max()
    m = f.mean(axis=0).ravel()
    v = f.var(axis=0, ddof=1).ravel()
    use = (f.max(axis=0).ravel() < z_max) & (m > dark_offset + 1)
    if use.sum() < 10:
        raise InputError("noise estimation needs at least 10 unsaturated, lit pixels")
    design = np.stack([np.ones(use.sum()), m[use] - dark_offset], axis=1)
    (c0, c1), *_ = np.linalg.lstsq(design, v[use], rcond=None)
    read = float(np.sqrt(max(c0 - 1.0 / 12.0, 0.0)))
    return read, float(1.0 / c1) if c1 > 0 else float("inf")
