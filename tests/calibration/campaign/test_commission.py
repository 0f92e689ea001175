"""``heliocal commission`` driven by flags against the embedded simulated plant."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from controller.recognition.library_io import load_library
from tests.conftest import scaled_s

REPO = Path(__file__).resolve().parents[3]


def _run(*args, env=None):
    return subprocess.run(
        [sys.executable, "-m", "controller.cli", "commission", *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )


def test_a_simulated_session_without_a_run_dir_leaves_nothing_behind(small_config, tmp_path):
    """Without ``--run-dir`` the simulated plant's ptys and files go to a temporary folder that
    is removed at the end (each run left one in the temporary folder before 2026-11-30)."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    r = _run("--config", str(small_config), "--heliostat", "H02", "--simulate", "--status", "--json",
             env={**os.environ, "TMPDIR": str(tmp)})
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["steps"]["status"]["az_steps"] == 500
    assert list(tmp.iterdir()) == []


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
    assert steps["verify"]["tolerance_mrad"] == 0.5 and steps["verify"]["error_mrad"] > 0
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


@pytest.mark.parametrize("line, expected", [
    ("m 100 200", ("move", (100, 200))), ("jog -5 7", ("jog", (-5, 7))), ("c f.png", ("capture", ("f.png",))),
    ("", None), ("q", ("q", ())), ("p", ("park", ())),
])
def test_prompt_lines(line, expected):
    from controller.commands.commission import parse_prompt

    assert parse_prompt(line) == expected


@pytest.mark.parametrize("line, fragment", [
    ("m 1", "usage: move AZ EL"), ("m 1 x", "usage: move AZ EL"), ("c", "usage: capture FILE.png"),
    ("r", "usage: reference LABEL"), ("s extra", "usage: status"), ("fly", "unknown command 'fly'"),
    ("c 'open", "cannot read the line"),
])
def test_bad_prompt_lines_give_usage(line, fragment):
    from controller.commands.commission import parse_prompt
    from controller.errors import InputError

    with pytest.raises(InputError, match=re.escape(fragment)):
        parse_prompt(line)


def _session(small_config, tmp_path, *extra):
    return subprocess.Popen(
        [sys.executable, "-m", "controller.cli", "commission", "--config", str(small_config), "--heliostat",
         "H02", "--simulate", "--run-dir", str(tmp_path / "run"), *extra],
        cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for(stream, fragment: str) -> str:
    seen = ""
    while fragment not in seen:
        line = stream.readline()
        assert line, f"no {fragment!r} in {seen!r}"
        seen += line
    return seen


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_mid_move_parks_the_heliostat(small_config, tmp_path, sig):
    """A long move is under way when the signal comes: the session parks at standby, says so
    with the position read back from the firmware, and exits 130."""
    p = _session(small_config, tmp_path)
    _wait_for(p.stderr, "'h' for help")
    p.stdin.write("m 30000 30000\n")
    p.stdin.flush()
    _wait_for(p.stderr, "move 30000 30000")
    p.send_signal(sig)
    out, err = p.communicate(timeout=scaled_s(120))
    assert p.returncode == 130, err
    said = re.search(r"H02 parked at standby \(az (\d+), el (\d+)\)", err)
    assert said, err
    assert (int(said[1]), int(said[2])) != (30000, 30000)


def test_end_of_input_parks_and_leave_in_place_does_not(small_config, tmp_path):
    p = _session(small_config, tmp_path)
    _, err = p.communicate("m 20000 20000\n", timeout=scaled_s(120))
    assert p.returncode == 0 and "H02 parked at standby" in err, err
    p = _session(small_config, tmp_path / "b", "--leave-in-place")
    out, err = p.communicate("m 20000 20000\nq\n", timeout=scaled_s(120))
    assert p.returncode == 0 and "left in place" in err and "parked" not in err
    assert "az 20000 el 20000 steps, in position, no faults" in out


def test_bad_prompt_line_does_not_end_the_session(small_config, tmp_path):
    p = _session(small_config, tmp_path)
    out, err = p.communicate("m 1\nc\ns\nq\n", timeout=scaled_s(120))
    assert p.returncode == 0 and "Traceback" not in err
    assert out.count("error: usage:") == 2 and "az 500 el 500 steps" in out  # status still ran


def test_capture_at_stow_is_no_beam_and_nothing_is_computed_from_it(small_config, tmp_path):
    # At stow the beam is nowhere near the target: the capture says "no beam" with the presence
    # statistic, verify is not ok and has no error, and no reference case can be stored from it.
    base = ("--config", str(small_config), "--heliostat", "H02", "--simulate", "--json")
    r = _run(*base, "--run-dir", str(tmp_path / "run"), "--capture", str(tmp_path / "f.png"), "--verify")
    assert r.returncode == 0, r.stderr
    steps = json.loads(r.stdout)["steps"]
    for key in ("capture", "verify"):
        s = steps[key]
        assert s["beam"] is False and s["no_beam"] is True and s["statistic"] < s["threshold"], s
        assert "no beam on the target" in s["problem"] and "error_mrad" not in s
    assert steps["verify"]["ok"] is False
    r = _run(*base, "--run-dir", str(tmp_path / "run2"), "--store-reference", "x", "--library",
             str(tmp_path / "lib.yaml"))
    assert r.returncode == 2
    assert "cannot store a reference case: no beam on the target" in r.stdout + r.stderr
    assert not (tmp_path / "lib.yaml").exists()
