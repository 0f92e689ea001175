"""Model of one CCD sensor of the double-CCD camera: response, offset, noise, quantisation.

Units and conventions
---------------------
Scene irradiance is given per pixel in **counts per second at unit gain before response**:
a pixel of irradiance ``E`` exposed for ``t`` seconds collects the *linear signal*
``s = gain * E * t`` counts. "Counts" are those of the linear part of the output range,
so ``s = z_max - dark_offset`` just fills the full well. The pipeline of :meth:`SensorModel.expose`:

1. shot noise: ``e ~ Poisson(s * k)`` electrons, ``k = full_well / (z_max - a)`` e⁻/count,
   clipped at the full well (this is where the sensor saturates); with ``shot="gauss"`` the
   normal approximation ``e ~ N(λ, λ)``, ``λ = s * k`` (see below);
2. response: ``z = a + (z_max - a) * f(e / full_well)``, with ``f`` monotone on [0, 1],
   ``f(0) = 0``, ``f(1) = 1`` (linear when ``response`` is None);
3. read noise: Gaussian, ``read_noise`` counts RMS, added after the response;
4. quantisation: rounding to integers and clipping to ``[0, z_max]``, ``z_max = 2**N - 1``;
   a pixel at full well reads ``z_max`` exactly (the ADC clip sits at the full well).

**Gaussian shot noise** (``shot="gauss"``, what the simulated plant's cameras use): drawing
a Poisson variate costs ~60 ns a pixel, five times a normal one, and two 1024 x 768 frames
a capture made it the plant's largest cost. After the response, read noise and quantisation
the two are indistinguishable when the read noise in electrons, ``σ_e = read_noise * k``, is
well above one electron: the lattice of the Poisson counts is smoothed away (ripple
``exp(-2π² σ_e²)``) and the skewness of a pixel's total noise, ``λ / (λ + σ_e²)^(3/2)``, is
at most ``0.385 / σ_e`` (8-bit demo camera: σ_e ≈ 65 e⁻, skewness ≤ 0.006). The normal
variate is not clipped at zero, so each pixel keeps mean and variance λ; ``tests/imaging/
test_sensor.py`` compares the output counts with an exact Poisson pipeline.

:meth:`SensorModel.inverse_response` gives the noise-free inverse ``I(z)`` (exposure value
``E * t``, in the irradiance units above times seconds) in the layout of the CRF file, so
tests and the simulated camera can hand the merge the sensor's true response.

References
----------
.. [1] Janesick, J. R., "Photon Transfer", SPIE Press, 2007 (shot/read noise model).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

Response = Callable[[np.ndarray], np.ndarray]

# Read noise (electrons) from which a camera may use Gaussian shot noise: skewness of a
# pixel's total noise at most 0.385 / 30 ≈ 0.013, the Poisson lattice invisible.
GAUSS_SHOT_MIN_READ_E = 30.0


def shot_law(read_noise_counts: float, full_well: float, bit_depth: int, dark_offset: float) -> str:
    """``"gauss"`` when the read noise in electrons, ``read_noise * full_well / (z_max - a)``,
    is at least ``GAUSS_SHOT_MIN_READ_E`` (the normal approximation is then invisible in the
    output, module docstring), else ``"poisson"``."""
    sigma_e = read_noise_counts * full_well / ((1 << bit_depth) - 1 - dark_offset)
    return "gauss" if sigma_e >= GAUSS_SHOT_MIN_READ_E else "poisson"


def knee_response(knee: float) -> Response:
    """A mildly compressive, invertible response ``f(u) = (1 + b) u / (1 + b u)``.

    Parameters
    ----------
    knee : float
        ``b >= 0``; the slope is ``1 + b`` at ``u = 0`` and ``1 / (1 + b)`` at ``u = 1``.
        ``b = 0`` is linear. ``u`` is the linear signal as a fraction of full scale.

    Returns
    -------
    callable mapping u in [0, 1] to the output fraction of full scale in [0, 1].
    """
    if knee < 0:
        raise ValueError("knee must be >= 0")

    def f(u: np.ndarray) -> np.ndarray:
        u = np.asarray(u)
        u = u if u.dtype.kind == "f" else u.astype(float)  # float32 stays float32 (fast path)
        return (1.0 + knee) * u / (1.0 + knee * u)

    return f


@dataclass(frozen=True)
class SensorModel:
    """One sensor. ``dark_offset`` and ``read_noise`` in output counts, ``full_well`` in
    electrons, ``gain`` relative (multiplies the linear signal), ``response`` see
    :func:`knee_response` (None: linear), ``shot`` the shot-noise law: ``"poisson"`` (exact)
    or ``"gauss"`` (its normal approximation, module docstring)."""

    bit_depth: int = 8
    dark_offset: float = 8.0
    read_noise: float = 0.8
    full_well: float = 20000.0
    gain: float = 1.0
    response: Response | None = None
    shot: str = "poisson"

    def __post_init__(self) -> None:
        if self.shot not in ("poisson", "gauss"):
            raise ValueError(f"shot must be 'poisson' or 'gauss', got {self.shot!r}")
        if not 1 <= self.bit_depth <= 16:
            raise ValueError("bit_depth must be in 1..16")
        if not 0 <= self.dark_offset < self.z_max:
            raise ValueError("dark_offset must be in [0, 2**bit_depth - 1)")
        if self.read_noise < 0 or self.full_well <= 0 or self.gain <= 0:
            raise ValueError("read_noise must be >= 0, full_well and gain > 0")

    @property
    def z_max(self) -> int:
        return (1 << self.bit_depth) - 1

    @property
    def span(self) -> float:
        """Output counts above the dark offset: ``z_max - dark_offset``."""
        return self.z_max - self.dark_offset

    @property
    def electrons_per_count(self) -> float:
        """Conversion factor k (e⁻ per linear count): the full well fills the span."""
        return self.full_well / self.span

    def _f(self, u: np.ndarray) -> np.ndarray:
        return u if self.response is None else np.asarray(self.response(u), dtype=float)

    def expose(self, irradiance: np.ndarray, exposure_s: float, rng: np.random.Generator) -> np.ndarray:
        """Simulate one exposure.

        Parameters
        ----------
        irradiance : ndarray, shape (rows, cols)
            Counts per second at unit gain before response (>= 0).
        exposure_s : float
            Exposure time in seconds.
        rng : numpy Generator
            Source of shot and read noise.

        Returns
        -------
        ndarray (rows, cols), uint8 for bit_depth <= 8, else uint16.
        """
        if self.shot == "gauss":
            return self._expose_gauss(irradiance, exposure_s, rng)
        e_mean = np.clip(np.asarray(irradiance, dtype=float), 0.0, None) * (
            exposure_s * self.gain * self.electrons_per_count)
        # Poisson is exact; cap the mean far above the full well (the result clips anyway).
        electrons = np.minimum(rng.poisson(np.minimum(e_mean, 4.0 * self.full_well)), self.full_well)
        z = self.dark_offset + self.span * self._f(electrons / self.full_well)
        if self.read_noise > 0:
            z = z + rng.normal(0.0, self.read_noise, size=z.shape)
        return self._quantise(z, electrons)

    def _expose_gauss(self, irradiance: np.ndarray, exposure_s: float,
                      rng: np.random.Generator) -> np.ndarray:
        """:meth:`expose` with shot noise N(λ, λ) (module docstring), in float32: 24 bits of
        mantissa resolve well below one electron up to the 4x full-well cap (and 1/100 of a
        count of a 16-bit ADC). Not clipped at 0, so every pixel keeps mean and variance λ."""
        f32 = np.float32
        scale = f32(exposure_s * self.gain * self.electrons_per_count)
        lam = np.maximum(np.asarray(irradiance, dtype=f32), f32(0.0)) * scale
        np.minimum(lam, f32(4.0 * self.full_well), out=lam)
        electrons = lam + np.sqrt(lam) * rng.standard_normal(lam.shape, dtype=f32)
        np.minimum(electrons, f32(self.full_well), out=electrons)
        u = electrons / f32(self.full_well)
        fu = u if self.response is None else self.response(u).astype(f32)
        z = f32(self.dark_offset) + f32(self.span) * fu
        if self.read_noise > 0:
            z += f32(self.read_noise) * rng.standard_normal(z.shape, dtype=f32)
        return self._quantise(z, electrons)

    def _quantise(self, z: np.ndarray, electrons: np.ndarray) -> np.ndarray:
        """Output counts: ``z`` rounded and clipped to the ADC range, full wells at ``z_max``."""
        z = np.clip(np.rint(z), 0, self.z_max)
        # A full well reads z_max exactly: the ADC range ends at the full well, so read noise
        # cannot pull a saturated pixel below the clip.
        z[electrons >= self.full_well] = self.z_max
        return z.astype(np.uint8 if self.bit_depth <= 8 else np.uint16)

    def expected_value(self, irradiance: np.ndarray, exposure_s: float) -> np.ndarray:
        """Noise-free, unquantised output counts (float) for an irradiance and exposure."""
        u = np.clip(np.asarray(irradiance, dtype=float) * exposure_s * self.gain / self.span, 0.0, 1.0)
        return self.dark_offset + self.span * self._f(u)

    def inverse_response(self) -> np.ndarray:
        """Noise-free inverse response ``I(z)``, shape (2**bit_depth,), non-decreasing.

        ``I(z)`` is the exposure value ``E * t`` (irradiance units above times seconds) whose
        expected output is ``z``; 0 at and below the dark offset, and at ``z_max`` the
        saturation exposure value (a lower bound for saturated pixels).
        """
        u = np.linspace(0.0, 1.0, 20001)
        out = self.dark_offset + self.span * self._f(u)
        z = np.arange(self.z_max + 1, dtype=float)
        return np.interp(z, out, u, left=0.0, right=1.0) * self.span / self.gain
