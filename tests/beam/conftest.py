"""Fixtures for the beam-analysis / recognition tests (helpers live in beamkit.py)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from beamkit import TOWER, heliocal  # noqa: E402


@pytest.fixture(scope="session")
def towers() -> dict:
    return json.loads(TOWER.read_text())


@pytest.fixture(scope="session")
def errorset(tmp_path_factory) -> Path:
    """The default error set (6 cases x 14 views, seed 0), rendered once per session."""
    out = tmp_path_factory.mktemp("errorset")
    r = heliocal("sim", "errorset", "--out", str(out), "--json")
    assert r.returncode == 0, r.stderr
    return out
