"""Helpers shared by the CLI command modules: JSON output, --config option, file checks."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from controller.errors import InputError

DEFAULT_CONFIG = "configs/demo.yaml"


def add_config_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config", default=DEFAULT_CONFIG, metavar="FILE",
        help=f"plant configuration YAML (default: {DEFAULT_CONFIG})",
    )


def add_json_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def _plain(value: Any) -> Any:
    """Convert numpy scalars/arrays and tuples into JSON-serialisable Python values."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return _plain(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def print_json(obj: Any) -> None:
    """Print ``obj`` as one line of JSON (numpy values converted, non-finite floats as null)."""
    print(json.dumps(_plain(obj)))


def existing_file(path: str | Path, what: str = "file") -> Path:
    """Return ``path`` as a Path, or raise InputError naming it when it is not a readable file."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{what} not found: {p}")
    return p
