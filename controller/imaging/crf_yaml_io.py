"""The CRF YAML file as plain data: read the document, write it atomically (its format:
:mod:`controller.imaging.crf`).

The bottom of the CRF's file handling: it knows nothing of :class:`controller.imaging.crf.Crf`,
so the domain's older entry points (``Crf.load``, ``Crf.save``) and
:mod:`controller.imaging.crf_io` both build on it without importing each other.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from controller.io.images import write_atomic
from controller.io.yaml_files import load_yaml


def read_crf_document(path: str | Path) -> object:
    """The parsed YAML document of a CRF file; InputError names the file on any problem."""
    return load_yaml(path, "CRF file")


def write_crf_document(doc: dict, path: str | Path) -> None:
    """Write a CRF document (``Crf.to_mapping()``) as YAML, atomically."""
    text = "# sensors in image order: first = shorter exposure (LOW), second = HIGH\n"
    text += yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=100)
    write_atomic(path, lambda t: t.write_text(text, encoding="utf-8"))
