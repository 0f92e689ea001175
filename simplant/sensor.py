"""Model of one CCD sensor of the double-CCD camera: response, offset, noise, quantisation.

Units and conventions
---------------------
Scene irradiance is given per pixel in **counts per second at unit gain before response**:
a pixel of irradiance ``E`` exposed for ``t`` seconds collects the *linear signal*
``s = gain * E * t`` counts. "Counts" are those of the linear part of the output range,
so ``s = z_max - dark_offset`` just fills the full well. The pipeline of :meth:`SensorModel.expose`:

1. shot noise: ``e ~ Poisson(s * k)`` electrons, ``k = full_well / (z_max - a)`` e⁻/count,
   clipped at the full well (this is where the sensor saturates);
2. response: ``z = a + (z_max - a) * f(e / full_well)``, with ``f`` monotone on [0, 1],
   ``f(0) = 0``, ``f(1) = 1`` (linear when ``response`` is None);
3. read noise: Gaussian, ``read_noise`` counts RMS, added after the response;
4. quantisation: rounding to integers and clipping to ``[0, z_max]``, ``z_max = 2**N - 1``;
   a pixel at full well reads ``z_max`` exactly (the ADC clip sits at the full well).

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
        u = np.asarray(u, dtype=float)
        return (1.0 + knee) * u / (1.0 + knee * u)

    return f


@dataclass(frozen=True)
class SensorModel:
    """One sensor. ``dark_offset`` and ``read_noise`` in output counts, ``full_well`` in
    electrons, ``gain`` relative (multiplies the linear signal), ``response`` see
    :func:`knee_response` (None: linear)."""

    bit_depth: int = 8
    dark_offset: float = 8.0
    read_noise: float = 0.8
    full_well: float = 20000.0
    gain: float = 1.0
    response: Response | None = None

    def __post_init__(self) -> None:
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
        e_mean = np.clip(np.asarray(irradiance, dtype=float), 0.0, None) * (
            exposure_s * self.gain * self.electrons_per_count)
        # Poisson is exact; cap the mean far above the full well (the result clips anyway).
        electrons = np.minimum(rng.poisson(np.minimum(e_mean, 4.0 * self.full_well)), self.full_well)
        z = self.dark_offset + self.span * self._f(electrons / self.full_well)
        if self.read_noise > 0:
            z = z + rng.normal(0.0, self.read_noise, size=z.shape)
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
