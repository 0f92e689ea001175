"""Example commands of docs/ run as written, and their documented figures checked (issue 27):
commissioning.md's session on the simulated plant, modbus.md's ephemeral port, cli.md's
refusal of a missing output folder."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"


def _heliocal(*args: str, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "controller.cli", *args], capture_output=True, text=True,
                          cwd=cwd, timeout=timeout)


def test_the_commissioning_example_prints_the_documented_figures(tmp_path):
    doc = (DOCS / "commissioning.md").read_text(encoding="utf-8")
    block = doc[doc.index("$ heliocal commission --heliostat H05"):]
    block = block[:block.index("```")]
    argv = re.sub(r"\\\n\s*", "", block.splitlines()[0] + "\n" + block.splitlines()[1]).split()[2:]
    r = _heliocal(*argv, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    steps = json.loads(r.stdout.strip().splitlines()[-1])["steps"]
    cx, cy = steps["capture"]["centroid_px"]
    aim, park = steps["aim"], steps["park"]
    shown = {"aim": f'"az_steps": {aim["az_steps"]}, "el_steps": {aim["el_steps"]}',
             "centroid": f'"centroid_px": [{cx:.1f}, {cy:.1f}]',
             "capture error": f'"error_mrad": {steps["capture"]["error_mrad"]:.2f}',
             "verify": f'"error_mrad": {steps["verify"]["error_mrad"]:.2f}, '
                       f'"tolerance_mrad": {steps["verify"]["tolerance_mrad"]}',
             "park": f'"az_steps": {park["az_steps"]}, "el_steps": {park["el_steps"]}'}
    for what, text in shown.items():
        assert text in block, f"docs/commissioning.md: {what}: the command prints {text}"


def test_sim_firmware_on_port_0_binds_a_free_port_as_modbus_md_says(tmp_path):
    assert "`heliocal sim firmware --modbus-tcp 127.0.0.1:0` binds a free" in (DOCS / "modbus.md").read_text()
    proc = subprocess.Popen([sys.executable, "-m", "controller.cli", "sim", "firmware", "--modbus-tcp",
                             "127.0.0.1:0", "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=tmp_path)
    try:
        line = json.loads(proc.stdout.readline())
        assert line["ok"] is True and line["port"] > 0 and line["link"] == f"127.0.0.1:{line['port']}"
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def test_a_missing_output_folder_is_refused_as_cli_md_says(tmp_path):
    doc = (DOCS / "cli.md").read_text(encoding="utf-8")
    ex = DOCS / "examples"
    r = _heliocal("flux", str(ex / "rx.png"), "--sun", str(ex / "sun.png"), "--dni", "900", "--reflectivity",
                  "0.9", "--sun-transmittance", "0.01", "--out", "a/f.npy", cwd=tmp_path)
    assert r.returncode == 2 and "--out a/f.npy: folder a does not exist (create it first)" in r.stderr
    assert "(`--out a/f.npy: folder a does not exist\n  (create it first)`)" in doc
    r = _heliocal("demo", "--heliostats", "1", "--aim-only", "--out", "a/b/d", cwd=tmp_path)
    assert r.returncode == 2 and "--out a/b/d: parent folder a/b does not exist (create it first)" in r.stderr
    assert not any(tmp_path.iterdir())
