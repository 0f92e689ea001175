"""CRF files: the YAML document of :mod:`controller.imaging.crf` and integrating-sphere CSV data."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from controller.errors import InputError
from controller.imaging.crf import Crf, SensorFit, fit_crf
from controller.imaging.crf_yaml_io import read_crf_document, write_crf_document
from controller.io.text_numbers import parse_float
from controller.io.yaml_files import read_text

MAX_SPHERE_ROWS = 1_000_000
MAX_CSV_BYTES = 64 << 20  # a million rows of "sensor,exposure_value,pixel_mean"


def load_crf(path: str | Path) -> Crf:
    """Read a CRF YAML file; InputError names the file and key on any problem."""
    return Crf.from_mapping(read_crf_document(path), str(path))


def save_crf(crf: Crf, path: str | Path) -> None:
    """Write the CRF YAML atomically."""
    write_crf_document(crf.to_mapping(), path)


def read_sphere_csv(path: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Read ``sensor,exposure_value,pixel_mean`` rows; returns {sensor: (X, z)} in file order."""
    p = Path(path)
    try:
        with io.StringIO(read_text(p, "CSV file", MAX_CSV_BYTES), newline="") as fh:
            reader = csv.DictReader(fh)
            need = {"sensor", "exposure_value", "pixel_mean"}
            if reader.fieldnames is None or not need <= {f.strip() for f in reader.fieldnames}:
                raise InputError(f"{p}: header must contain the columns sensor,exposure_value,pixel_mean "
                                 f"(got {','.join(reader.fieldnames or [])})")
            data: dict[str, tuple[list, list]] = {}
            for line, row in enumerate(reader, start=2):
                if line > MAX_SPHERE_ROWS:
                    raise InputError(f"{p}: more than {MAX_SPHERE_ROWS} rows")
                row = {k.strip(): (v or "").strip() for k, v in row.items() if k}
                try:
                    xv = parse_float(row["exposure_value"], "exposure_value")
                    zv = parse_float(row["pixel_mean"], "pixel_mean")
                except InputError:
                    raise InputError(f"{p}: line {line}: exposure_value and pixel_mean must be "
                                     "numbers") from None
                if not (np.isfinite(xv) and np.isfinite(zv)) or xv < 0 or zv < 0:
                    raise InputError(f"{p}: line {line}: values must be finite and >= 0")
                xs, zs = data.setdefault(row["sensor"], ([], []))
                xs.append(xv)
                zs.append(zv)
    except OSError as exc:
        raise InputError(f"{p}: cannot read CSV: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise InputError(f"{p}: not a UTF-8 text CSV file") from None
    except csv.Error as exc:  # a NUL byte, a field over the csv module's limit
        raise InputError(f"{p}: malformed CSV ({exc})") from None
    if len(data) != 2:
        raise InputError(f"{p}: column sensor must name exactly 2 sensors, got {len(data)}")
    return {k: (np.array(v[0]), np.array(v[1])) for k, v in data.items()}


def fit_crf_file(path: str | Path, bit_depth: int = 8) -> tuple[Crf, list[SensorFit]]:
    """:func:`controller.imaging.crf.fit_crf` of an integrating-sphere CSV (sensor order as first
    seen in the file; the first must be the LOW sensor)."""
    return fit_crf(read_sphere_csv(path), bit_depth, str(path))
