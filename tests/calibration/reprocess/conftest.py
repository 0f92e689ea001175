"""The source archive the reprocessing tests share: a demo database recorded by the product on
the simulated plant (small cameras, three heliostats, the calibration night and one planned
night), with the plant's camera responses in its configuration, so the records were made with
exactly the configuration they name. Session-scoped: it is made once for every module here."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from controller.commands.simulated import plant_crf_config
from tests.conftest import scaled_s

REPO = Path(__file__).resolve().parents[3]


def heliocal(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    """``heliocal args`` as a process of the project's environment (``check``: exit 0)."""
    r = subprocess.run([sys.executable, "-m", "controller.cli", *args], cwd=REPO, capture_output=True,
                       text=True, timeout=scaled_s(600))
    if check:
        assert r.returncode == 0, r.stderr
    return r


@pytest.fixture(scope="session")
def field(tmp_path_factory) -> dict[str, Path]:
    """The demo database (module docstring): ``db``, its ``config`` and their folder ``dir``."""
    d = tmp_path_factory.mktemp("reprocess")
    config = plant_crf_config(d)
    r = heliocal("demo", "--config", str(config), "--heliostats", "3", "--nights", "1", "--out",
                 str(d / "demo"), "--json", check=False)
    # The demo exits with its worst night: 3 when a night left planned geometries unmeasured.
    partial = any(n["status"] == "partial" for n in json.loads(r.stdout)["nights"])
    assert r.returncode == (3 if partial else 0), r.stderr
    return {"db": d / "demo" / "campaign.db", "config": config, "dir": d}
