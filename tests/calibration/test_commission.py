"""``heliocal commission`` driven by flags against the embedded simulated plant."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from controller.calibration.library import load_library

REPO = Path(__file__).resolve().parents[2]


def _run(*args):
    return subprocess.run(
        [sys.executable, "-m", "controller.cli", "commission", *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_commission_steps(small_config, tmp_path):
    cfg = small_config
    lib = tmp_path / "lib" / "lib.yaml"
    r = _run(
        "--config",
        str(cfg),
        "--heliostat",
        "H02",
        "--simulate",
        "--run-dir",
        str(tmp_path / "run"),
        "--status",
        "--aim",
        "--jog-az",
        "20",
        "--capture",
        str(tmp_path / "f.png"),
        "--store-reference",
        "twist",
        "--library",
        str(lib),
        "--verify",
        "--park",
        "--json",
    )
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    steps = out["steps"]
    assert list(steps) == ["status", "aim", "jog", "capture", "reference", "verify", "park"]
    assert steps["status"]["az_steps"] == 500  # the simulated plant starts at stow
    assert steps["jog"]["az_steps"] == steps["aim"]["az_steps"] + 20
    assert steps["capture"]["beam"] and (tmp_path / "f.png").is_file()
    assert steps["verify"]["tolerance_mrad"] == 0.3 and steps["verify"]["error_mrad"] > 0
    assert steps["park"]["in_position"] and not steps["park"]["moving"]
    entries = load_library(lib).entries
    assert [e.label for e in entries] == ["twist"] and Path(entries[0].image).is_file()
    assert (
        (tmp_path / "lib" / "lib-manifest.csv").read_text().splitlines()[1].startswith("references/H02-twist")
    )


def test_commission_bad_input(small_config, tmp_path):
    cfg = small_config
    r = _run("--config", str(cfg), "--heliostat", "H02", "--simulate", "--store-reference", "x", "--json")
    assert r.returncode == 2 and "--library" in json.loads(r.stdout)["error"]
    r = _run("--config", str(cfg), "--heliostat", "H99", "--simulate", "--status")
    assert r.returncode == 2 and "H99" in r.stderr and "Traceback" not in r.stderr
    r = _run("--config", str(cfg), "--heliostat", "H02", "--simulate", "--move", "999999", "10", "--json")
    assert r.returncode == 2 and "soft limits" in json.loads(r.stdout)["error"]
