"""A new user's session, as the README tells it, run from a folder outside the repository
with no --config: every command answers without a traceback and with the documented exit
status (docs/cli.md)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from tests.conftest import scaled_s


def heliocal(cwd, *args, env=None):
    r = subprocess.run([sys.executable, "-m", "controller.cli", *args], cwd=cwd, capture_output=True,
                       text=True, timeout=scaled_s(300), env={**os.environ, **(env or {})})
    assert "Traceback" not in r.stderr, r.stderr
    return r


def test_readme_session_outside_the_repository(tmp_path):
    env = {"HELIOCAL_CONFIG": ""}  # nothing set: the packaged demo plant is used
    r = heliocal(tmp_path, "sun", "--time", "now", "--json", env=env)
    assert r.returncode == 0 and set(json.loads(r.stdout)) == {"zenith_deg", "azimuth_deg", "elevation_deg"}
    r = heliocal(tmp_path, "demo", "--aim-only", "--heliostats", "2", "--json", env=env)
    assert r.returncode == 0 and len(json.loads(r.stdout)["heliostats"]) == 2
    assert "using configuration" in r.stderr and "packaged demo plant" in r.stderr

    r = heliocal(tmp_path, "campaign", "run", "--db", "night.db", "--simulate", "--heliostats", "H02",
                 "--name", "first-night", "--report", "report", "--notify", "cat > notified.json", "--json",
                 env=env)
    summary = json.loads(r.stdout)
    assert r.returncode == {"finished": 0, "partial": 3}[summary["status"]], r.stderr
    assert summary["heliostats"] == 1 and (tmp_path / "report" / "report.html").is_file()
    assert json.loads((tmp_path / "notified.json").read_text()) == summary  # the scheduler's hook

    r = heliocal(tmp_path, "campaign", "list", "--db", "night.db", "--json")
    assert r.returncode == 0 and [c["name"] for c in json.loads(r.stdout)["campaigns"]] == ["first-night"]
    r = heliocal(tmp_path, "export", "--db", "night.db", "--format", "paint", "--out", "paint",
                 "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["records"] >= 1
    r = heliocal(tmp_path, "report", "campaign", "--db", "night.db", "--out", "again", "--campaign",
                 "first-night")
    assert r.returncode == 0 and (tmp_path / "again" / "heliostats.csv").is_file()


def test_bad_paths_exit_2_and_write_nothing(tmp_path):
    (tmp_path / "file.txt").write_text("not a folder")
    (tmp_path / "empty.db").write_bytes(b"")
    before = sorted(p.name for p in tmp_path.iterdir())
    for args in (["report", "campaign", "--db", "empty.db", "--out", "r"],
                 ["report", "campaign", "--db", "missing.db", "--out", "r"],
                 ["export", "--db", "empty.db", "--format", "paint", "--out", "p"],
                 ["campaign", "list", "--db", "file.txt"],
                 ["campaign", "run", "--db", "c.db", "--simulate", "--report", "file.txt/r"],
                 ["demo", "--heliostats", "99", "--out", "d"]):
        r = heliocal(tmp_path, *args)
        assert r.returncode == 2, (args, r.stderr)
        errors = [line for line in r.stderr.splitlines() if ": error: " in line]
        assert len(errors) == 1, (args, r.stderr)  # (a "using configuration" note may precede it)
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    assert (tmp_path / "empty.db").stat().st_size == 0
