"""Weighting functions w(z) for merging exposures (HDR paper Eq. (2)-(4) and classics).

All functions take pixel values ``z`` (any integer or float array) of an ``N``-bit sensor and
return float64 weights of the same shape. ``z_max = 2**N - 1`` and the mid value
``c = z_max / 2`` (127.5 for 8 bits); the 8-bit constants of the papers (255, 127.5) are
generalised through these two numbers.

References
----------
.. [1] The HDR paper: double-CCD HDR imaging for heliostat calibration, Eq. (1) (merge),
   Eq. (2)-(4) (raised-cosine weight with roll-off β and the dark-offset rule).
.. [2] Robertson, M. A., Borman, S., Stevenson, R. L., "Estimation-theoretic approach to
   dynamic range enhancement using multiple exposures", J. Electron. Imaging 12 (2003) 219.
.. [3] Debevec, P. E., Malik, J., "Recovering high dynamic range radiance maps from
   photographs", SIGGRAPH 1997.
.. [4] Mann, S., Picard, R. W., "Being 'undigital' with digital cameras", 1995;
   Mitsunaga, T., Nayar, S. K., "Radiometric self calibration", CVPR 1999.
.. [5] Reinhard, E. et al., "High Dynamic Range Imaging", Morgan Kaufmann, 2005.
.. [6] Granados, M. et al., "Optimal HDR reconstruction with linear digital cameras",
   CVPR 2010 (inverse-variance weighting).
"""

from __future__ import annotations

import numpy as np

NAMES = ("raised-cosine", "robertson", "debevec", "mitsunaga", "reinhard", "deneve", "noise-optimal")


def _levels(z, bit_depth: int) -> tuple[np.ndarray, float, float]:
    z_max = float((1 << bit_depth) - 1)
    return np.asarray(z, dtype=float), z_max, z_max / 2.0


def robertson(z, bit_depth: int = 8) -> np.ndarray:
    """Gaussian weight ``w = exp(-4 (z - c)² / c²)`` of Robertson et al. [2]_."""
    z, _, c = _levels(z, bit_depth)
    return np.exp(-4.0 * (z - c) ** 2 / c**2)


def debevec(z, bit_depth: int = 8) -> np.ndarray:
    """Hat weight of Debevec & Malik [3]_: ``z / c`` for ``z <= c``, ``(z_max - z) / c`` above."""
    z, z_max, c = _levels(z, bit_depth)
    return np.where(z <= c, z / c, (z_max - z) / c)


def mitsunaga(z, bit_depth: int = 8) -> np.ndarray:
    """Ramp weight (Mann & Picard; Mitsunaga & Nayar [4]_): ``z / z_max``, 0 at ``z_max``."""
    z, z_max, _ = _levels(z, bit_depth)
    return np.where(z < z_max, z / z_max, 0.0)


def reinhard(z, bit_depth: int = 8) -> np.ndarray:
    """Reinhard et al. [5]_: ``(z / z_max) [1 - (z / c - 1)^12]`` for ``z < z_max``, else 0."""
    z, z_max, c = _levels(z, bit_depth)
    return np.where(z < z_max, (z / z_max) * (1.0 - (z / c - 1.0) ** 12), 0.0)


def deneve(z, bit_depth: int = 8, a: float = 1.0, b: float = 1.0) -> np.ndarray:
    """Exponential-power weight ``w = exp(-|z - c|^a / (b c^a))`` for ``z < z_max``, 0 at ``z_max``.

    The paper describes it as an exponential power function that emphasises the middle of the
    range and ignores saturated pixels; its table entry lost the exponent of ``|z - c|`` (read
    literally, ``exp(-(z - c) / (b c^a))`` is monotone, exceeds 1 below ``c`` and is non-zero at
    saturation, contradicting that description). So: 1 at ``c``, symmetric about it, decreasing
    with ``|z - c|`` to ``exp(-1/b)`` at the ends of the range, and 0 for saturated pixels.
    ``a`` (> 0) sets how flat the top is, ``b`` (> 0) how low the ends fall; a = b = 1 by default.
    """
    if not a > 0 or not b > 0:
        raise ValueError("deneve constants a and b must be positive")
    z, z_max, c = _levels(z, bit_depth)
    return np.where(z < z_max, np.exp(-np.abs(z - c) ** a / (b * c**a)), 0.0)


def raised_cosine(z, dark_offset: float = 8.0, bit_depth: int = 8, roll_off_high: float = 1.0,
                  roll_off_low: float | None = None) -> np.ndarray:
    """Raised-cosine weight of the HDR paper [1]_, Eq. (2)-(4) — the default.

    With ``d = |z - c|`` and roll-off ``β``::

        w = 1                                             d <= c (1 - β) / 2
        w = ½ [1 + cos(π / (c β) · (d - c (1 - β) / 2))]    c (1 - β) / 2 < d <= c (1 + β) / 2
        w = 0                                             otherwise

    Parameters
    ----------
    z : array of pixel values (counts).
    dark_offset : dark-signal offset ``a`` in counts. The low side (``z < c``) uses
        ``β = 1 - 2a / c`` (Eq. (4)), so ``w = 0`` for ``z <= a``.
    bit_depth : N; ``c = (2**N - 1) / 2``.
    roll_off_high : β of the high side (``z >= c``); 1 (default) gives ``w = 0`` only at
        ``z_max`` (saturation).
    roll_off_low : override the low-side β (default: Eq. (4) from ``dark_offset``).

    Returns
    -------
    ndarray of weights in [0, 1].
    """
    z, _, c = _levels(z, bit_depth)
    beta_low = 1.0 - 2.0 * dark_offset / c if roll_off_low is None else roll_off_low
    if not 0 < beta_low <= 1 or not 0 < roll_off_high <= 1:
        raise ValueError("roll-off β must lie in (0, 1]; the dark offset must be below c/2")
    beta = np.where(z >= c, roll_off_high, beta_low)
    d = np.abs(z - c)
    flat = c * (1.0 - beta) / 2.0
    edge = c * (1.0 + beta) / 2.0
    w = 0.5 * (1.0 + np.cos(np.pi / (c * beta) * (d - flat)))
    w = np.where(d <= flat, 1.0, np.where(d <= edge, w, 0.0))
    # The low-side roll-off ends exactly at the offset; also zero anything at or below it.
    return np.where(z <= dark_offset, 0.0, w)


def exposure_variance(inverse_response: np.ndarray, dark_offset: float = 8.0, read_noise: float = 0.8,
                      electrons_per_count: float = 20000.0 / 247.0) -> np.ndarray:
    """Variance of the exposure value ``I(z)`` read from pixel value z, for every z: shape (2**N,).

    Photon-transfer noise model (Janesick, "Photon Transfer", SPIE Press, 2007)::

        var I(z) = (I(z) - I(a)) ΔI / FW  +  (r² + 1/12) I'(z)²

    The first term is shot noise: the full well ``FW = k (z_max - a)`` electrons spans
    ``ΔI = I(z_max) - I(a)`` exposure-value units, so one electron is ``ΔI / FW`` of them and a
    Poisson count of ``(I - I(a)) FW / ΔI`` electrons has that variance. The second is read
    noise ``r`` plus quantisation (1/12 count²) carried through the slope ``I'(z)`` of the inverse
    response. Equivalently ``var I = σ²(z) / f'(I)²`` with ``σ²(z)`` the pixel-value variance.

    Parameters
    ----------
    inverse_response : I(z), shape (2**N,), non-decreasing.
    dark_offset : a, counts. read_noise : r, counts RMS. electrons_per_count : k.
    """
    table = np.asarray(inverse_response, dtype=float)
    z_max = table.size - 1
    levels = np.arange(table.size, dtype=float)
    i_a = float(np.interp(dark_offset, levels, table))
    full_well = electrons_per_count * (z_max - dark_offset)
    shot = np.maximum(table - i_a, 0.0) * (table[-1] - i_a) / full_well
    return shot + (read_noise**2 + 1.0 / 12.0) * np.gradient(table) ** 2


def noise_optimal(z, inverse_response: np.ndarray, dark_offset: float = 8.0, read_noise: float = 0.8,
                  electrons_per_count: float = 20000.0 / 247.0, bit_depth: int = 8,
                  taper_sigmas: float = 3.0) -> np.ndarray:
    """Inverse-variance weight ``w = f'(I(z))² / σ²(z) = 1 / var I(z)`` (beyond the paper; [6]_).

    ``f`` is the sensor response (exposure value -> counts) and ``σ²(z)`` the variance of the
    pixel value; ``var I(z)`` is :func:`exposure_variance`. With these weights Eq. (1) is the
    inverse-variance (maximum-likelihood) combination of the two exposures ``I_k / t_k``.

    Censoring taper: a value within a few σ of the dark offset or of the clip is only observed
    when the noise happened to push it inside, so it is biased away from the limit. The weight
    is multiplied by ``sin²(π/2 · min(1, d / (taper_sigmas σ)))``, ``d`` the distance in counts to
    the offset (or to ``z_max``) and ``σ`` the pixel-value noise there; ``taper_sigmas = 0``
    gives the bare inverse-variance weight.

    Parameters
    ----------
    z : pixel values.
    inverse_response : I(z) for z = 0 .. z_max, shape (2**N,), non-decreasing.
    dark_offset, read_noise : counts. electrons_per_count : k of the shot-noise term.
    bit_depth : N.

    Returns
    -------
    ndarray of weights (units 1 / exposure-value²); zero at and below the dark offset and at
    saturation (``z_max``).
    """
    z, z_max, _ = _levels(z, bit_depth)
    table = np.asarray(inverse_response, dtype=float)
    if table.shape != (int(z_max) + 1,):
        raise ValueError(f"inverse_response must have {int(z_max) + 1} entries")
    var = exposure_variance(table, dark_offset, read_noise, electrons_per_count)
    levels = np.arange(table.size, dtype=float)
    with np.errstate(divide="ignore"):
        w_table = np.where(var > 0, 1.0 / var, 0.0)
    if taper_sigmas > 0:
        sigma_z = np.sqrt(var) / np.maximum(np.gradient(table), 1e-300)
        s_lo = sigma_z[min(int(np.ceil(dark_offset)) + 1, int(z_max))]
        s_hi = sigma_z[int(z_max) - 1]
        ramp = np.minimum((levels - dark_offset) / (taper_sigmas * s_lo),
                          (z_max - levels) / (taper_sigmas * s_hi))
        w_table *= np.sin(0.5 * np.pi * np.clip(ramp, 0.0, 1.0)) ** 2
    w_table[(levels <= dark_offset) | (levels >= z_max)] = 0.0
    zi = np.clip(np.rint(z), 0, z_max).astype(np.int64)
    return w_table[zi]


def weight_table(name: str, *, bit_depth: int = 8, dark_offset: float = 8.0,
                 inverse_response: np.ndarray | None = None, read_noise: float = 0.8,
                 electrons_per_count: float = 20000.0 / 247.0, deneve_a: float = 1.0,
                 deneve_b: float = 1.0) -> np.ndarray:
    """Weights for every pixel value 0 .. 2**N - 1 of the named function (see :data:`NAMES`).

    ``inverse_response`` is needed by ``noise-optimal`` only (default: linear ``I(z) = z``).
    """
    z = np.arange(1 << bit_depth, dtype=float)
    if name == "raised-cosine":
        return raised_cosine(z, dark_offset, bit_depth)
    if name == "robertson":
        return robertson(z, bit_depth)
    if name == "debevec":
        return debevec(z, bit_depth)
    if name == "mitsunaga":
        return mitsunaga(z, bit_depth)
    if name == "reinhard":
        return reinhard(z, bit_depth)
    if name == "deneve":
        return deneve(z, bit_depth, deneve_a, deneve_b)
    if name == "noise-optimal":
        table = z if inverse_response is None else inverse_response
        return noise_optimal(z, table, dark_offset, read_noise, electrons_per_count, bit_depth)
    raise ValueError(f"unknown weighting {name!r} (choose from {', '.join(NAMES)})")
