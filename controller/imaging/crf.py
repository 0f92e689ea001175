"""Camera response functions (CRF) of the two sensors: document format, linear default, fitting.

Pure; the files are read and written by :mod:`controller.imaging.crf_io` (``Crf.load`` and
``Crf.save`` remain as compatibility entry points that import the YAML document's reader and
writer, :mod:`controller.imaging.crf_yaml_io`, lazily).

The CRF file (YAML) lists the sensors in image order, first = shorter exposure (LOW)::

    sensors:
      - name: ccd1
        bit_depth: 8
        inverse_response: [... 256 numbers ...]  # exposure value I(z), non-decreasing
        uncertainty_pct: 2.6                       # optional: fit uncertainty (1σ, %)
      - name: ccd2
        ...

``I(z)`` is the exposure value (exposure time × irradiance, linear units) that produces the
pixel value ``z``. Without a CRF the response is linear, ``I(z) = z`` (the dark offset is then
*not* subtracted; a fitted CRF has ``I(z) = 0`` at and below it).

Fitting (integrating-sphere data, CSV ``sensor,exposure_value,pixel_mean``): per sensor, the
non-saturated points are fitted by a monotone model ``z = g(X)``, a degree-``n`` Bernstein
polynomial of ``X / X_max`` with non-decreasing coefficients (bounded linear least squares),
and ``I(z) = g⁻¹(z)`` is tabulated. The uncertainty is the RMS relative deviation (%) between
``I(z_measured)`` and the known exposure value over the points above the dark level.

References
----------
.. [1] Lorentz, G. G., "Bernstein Polynomials", 1953 (monotone if the coefficients are).
.. [2] The HDR paper, Sect. on CRF calibration (integrating sphere; ±2.6 % and ±3.2 %).
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb
from pathlib import Path

import numpy as np

from controller.errors import InputError


@dataclass(frozen=True, eq=False)
class CrfSensor:
    """One sensor's inverse response: ``inverse_response[z] = I(z)``, shape (2**bit_depth,)."""

    name: str
    bit_depth: int
    inverse_response: np.ndarray
    uncertainty_pct: float | None = None


@dataclass(frozen=True, eq=False)
class Crf:
    """Inverse responses of the camera's sensors, LOW first."""

    sensors: tuple[CrfSensor, ...]

    @property
    def bit_depth(self) -> int:
        return self.sensors[0].bit_depth

    def inverse(self, index: int) -> np.ndarray:
        """I(z) table of sensor ``index`` (0 = LOW, 1 = HIGH)."""
        return self.sensors[index].inverse_response

    @classmethod
    def linear(cls, bit_depth: int = 8, dark_offset: float = 0.0,
               names: tuple[str, str] = ("ccd1", "ccd2")) -> Crf:
        """Linear response ``I(z) = max(z - dark_offset, 0)`` for both sensors."""
        z = np.arange(1 << bit_depth, dtype=float)
        table = np.maximum(z - dark_offset, 0.0)
        return cls(tuple(CrfSensor(n, bit_depth, table.copy()) for n in names))

    @classmethod
    def from_tables(cls, tables, names: tuple[str, ...] = ("ccd1", "ccd2")) -> Crf:
        """From inverse-response arrays (e.g. :meth:`SensorModel.inverse_response`)."""
        sensors = []
        for name, t in zip(names, tables, strict=True):
            t = np.asarray(t, dtype=float)
            bits = int(np.log2(t.size))
            sensors.append(CrfSensor(name, bits, t))
        crf = cls(tuple(sensors))
        crf.validate("<tables>")
        return crf

    def validate(self, source: str) -> None:
        """Raise InputError naming ``source`` and the key when the CRF is inconsistent."""
        if len(self.sensors) != 2:
            raise InputError(f"{source}: sensors: need exactly 2 sensors (LOW, HIGH), "
                             f"got {len(self.sensors)}")
        for i, s in enumerate(self.sensors):
            key = f"{source}: sensors[{i}]"
            if not 1 <= s.bit_depth <= 16:
                raise InputError(f"{key}.bit_depth: must be in 1..16, got {s.bit_depth}")
            n = 1 << s.bit_depth
            t = s.inverse_response
            if t.shape != (n,):
                raise InputError(f"{key}.inverse_response: needs {n} numbers for "
                                 f"bit_depth {s.bit_depth}, got {t.size}")
            if not np.all(np.isfinite(t)):
                raise InputError(f"{key}.inverse_response: contains NaN or infinite values")
            if np.any(np.diff(t) < 0):
                bad = int(np.argmax(np.diff(t) < 0)) + 1
                raise InputError(f"{key}.inverse_response[{bad}]: must be non-decreasing")
            if t[0] < 0 or t[-1] <= 0:
                raise InputError(f"{key}.inverse_response: values must be >= 0 and not all zero")
        if self.sensors[0].bit_depth != self.sensors[1].bit_depth:
            raise InputError(f"{source}: sensors: both sensors must have the same bit_depth")

    @classmethod
    def load(cls, path: str | Path) -> Crf:
        """Read a CRF YAML file; InputError names the file and key on any problem.

        A public entry point older than the split of file handling out of the domain: it reads
        the document through :mod:`controller.imaging.crf_yaml_io` (imported here, lazily), as
        :func:`controller.imaging.crf_io.load_crf` does."""
        from controller.imaging.crf_yaml_io import read_crf_document

        return cls.from_mapping(read_crf_document(path), str(path))

    @classmethod
    def from_mapping(cls, data: object, source: str) -> Crf:
        """Validate a parsed CRF document (module docstring); errors name ``source`` and the key."""
        p = source
        if not isinstance(data, dict) or not isinstance(data.get("sensors"), list):
            raise InputError(f"{p}: sensors: required key is missing (a list of 2 sensors)")
        sensors = []
        for i, item in enumerate(data["sensors"]):
            key = f"{p}: sensors[{i}]"
            if not isinstance(item, dict):
                raise InputError(f"{key}: must be a mapping")
            unknown = set(item) - {"name", "bit_depth", "inverse_response", "uncertainty_pct"}
            if unknown:
                raise InputError(f"{key}.{sorted(unknown)[0]}: unknown key")
            for k in ("name", "bit_depth", "inverse_response"):
                if k not in item:
                    raise InputError(f"{key}.{k}: required key is missing")
            if not isinstance(item["bit_depth"], int):
                raise InputError(f"{key}.bit_depth: must be an integer")
            try:
                table = np.asarray(item["inverse_response"], dtype=float)
            except (TypeError, ValueError):
                raise InputError(f"{key}.inverse_response: must be a list of numbers") from None
            if table.ndim != 1:
                raise InputError(f"{key}.inverse_response: must be a flat list of numbers")
            unc = item.get("uncertainty_pct")
            sensors.append(CrfSensor(str(item["name"]), item["bit_depth"], table,
                                     None if unc is None else float(unc)))
        crf = cls(tuple(sensors))
        crf.validate(str(p))
        return crf

    def to_mapping(self) -> dict:
        """The CRF document (module docstring) as plain data."""
        doc: dict = {"sensors": []}
        for sensor in self.sensors:
            item = {"name": sensor.name, "bit_depth": sensor.bit_depth,
                    "inverse_response": [round(float(v), 9) for v in sensor.inverse_response]}
            if sensor.uncertainty_pct is not None:
                item["uncertainty_pct"] = round(float(sensor.uncertainty_pct), 3)
            doc["sensors"].append(item)
        return doc

    def save(self, path: str | Path) -> None:
        """Write the CRF YAML atomically.

        Like :meth:`load`, a public entry point older than the split of file handling out of the
        domain: it writes through :mod:`controller.imaging.crf_yaml_io` (imported here, lazily), as
        :func:`controller.imaging.crf_io.save_crf` does."""
        from controller.imaging.crf_yaml_io import write_crf_document

        write_crf_document(self.to_mapping(), path)


def _bernstein(x: np.ndarray, degree: int) -> np.ndarray:
    """Bernstein basis B_{k,n}(x), shape (len(x), n + 1)."""
    x = np.clip(x, 0.0, 1.0)[:, None]
    k = np.arange(degree + 1)
    coef = np.array([comb(degree, i) for i in k], dtype=float)
    return coef * x**k * (1.0 - x) ** (degree - k)


@dataclass(frozen=True)
class SensorFit:
    """Result of fitting one sensor: its table, the fit uncertainty and the points used."""

    sensor: CrfSensor
    uncertainty_pct: float
    points_used: int
    points_saturated: int
    dark_level: float


def fit_sensor(name: str, exposure_value: np.ndarray, pixel_mean: np.ndarray, bit_depth: int = 8,
               degree: int = 6) -> SensorFit:
    """Fit a monotone response to (exposure value, mean pixel value) points of one sensor.

    Points with ``pixel_mean >= z_max - 0.5`` (saturated) are ignored. Model:
    ``z = Σ_k β_k B_{k,n}(X / X_max)`` with ``β_0 >= 0`` and ``β_k - β_{k-1} >= 0`` (monotone,
    Bernstein [1]_), solved by bounded linear least squares; ``I(z)`` is its inverse, 0 at and
    below ``β_0`` (the dark level), extrapolated linearly with the end slope above the data.
    """
    z_max = (1 << bit_depth) - 1
    x = np.asarray(exposure_value, dtype=float)
    z = np.asarray(pixel_mean, dtype=float)
    sat = z >= z_max - 0.5
    x, z = x[~sat], z[~sat]
    if x.size < degree + 2 or np.unique(x).size < 3:
        raise InputError(f"sensor {name!r}: needs at least {degree + 2} unsaturated points "
                         f"with 3 distinct exposure values, got {x.size}")
    x_max = float(x.max())
    basis = _bernstein(x / x_max, degree)
    # β = L δ with L lower-triangular ones: δ_0 = β_0, δ_k = β_k - β_{k-1} >= 0.
    design = basis @ np.tril(np.ones((degree + 1, degree + 1)))
    # Imported here: scipy.optimize costs ~0.4 s, which every CLI start would otherwise pay.
    from scipy.optimize import lsq_linear

    sol = lsq_linear(design, z, bounds=(0.0, np.inf))
    beta = np.cumsum(sol.x)
    grid = np.linspace(0.0, 1.0, 4001)
    g = _bernstein(grid, degree) @ beta
    levels = np.arange(z_max + 1, dtype=float)
    end_slope = max(degree * (beta[-1] - beta[-2]), 1e-9)  # dz/d(X/X_max) at X = X_max
    # np.interp needs strictly increasing abscissae; flat stretches of g are removed.
    keep = np.concatenate([[True], np.diff(g) > 1e-12])
    table = np.interp(levels, g[keep], grid[keep], left=0.0, right=1.0)
    above = levels > g[-1]
    table[above] = 1.0 + (levels[above] - g[-1]) / end_slope
    table = np.maximum.accumulate(table * x_max)
    dark = float(beta[0])
    lit = z > dark + 2.0
    pred = np.interp(z[lit], levels, table)
    unc = float(np.sqrt(np.mean(((pred - x[lit]) / x[lit]) ** 2)) * 100.0) if lit.any() else float("nan")
    return SensorFit(CrfSensor(name, bit_depth, table, unc), unc, int(x.size), int(sat.sum()), dark)


def fit_crf(samples: dict[str, tuple[np.ndarray, np.ndarray]], bit_depth: int = 8,
            source: str = "<data>") -> tuple[Crf, list[SensorFit]]:
    """Fit both sensors from integrating-sphere samples ``{sensor: (exposure_value, pixel_mean)}``
    (arrays, in sensor order: the first must be the LOW sensor)."""
    fits = []
    for name, (x, z) in samples.items():
        try:
            fits.append(fit_sensor(name, x, z, bit_depth))
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None
    crf = Crf(tuple(fit.sensor for fit in fits))
    crf.validate(source)
    return crf, fits
