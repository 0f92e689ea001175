"""End to end through the command line: ``heliocal sim firmware --modbus-tcp|--modbus-rtu``
serving, ``heliocal drive --modbus-tcp|--modbus-rtu ... --json`` driving (issue 6 contract)."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
CONFIG = str(REPO / "configs/demo.yaml")


@pytest.fixture
def heliocal(capsys):
    """Run ``heliocal ARGS`` in this process (the firmware runs in a child process; starting
    the CLI costs ~2 s of imports per process). Returns (exit status, stdout, stderr)."""
    from controller.cli import main

    def run(*args: str) -> tuple[int, str, str]:
        code = main(list(args))
        out = capsys.readouterr()
        return code, out.out, out.err

    return run


def free_port() -> int:
    # The link options need a real port number (1..65535), so pick one that was just free.
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(params=["tcp", "rtu"])
def firmware(request, tmp_path):
    """A running ``heliocal sim firmware`` (units 1 and 3, physics 20x real time); yields the
    link options for ``heliocal drive``."""
    where = f"127.0.0.1:{free_port()}" if request.param == "tcp" else str(tmp_path / "bus")
    proc = subprocess.Popen(
        [sys.executable, "-m", "controller.cli", "sim", "firmware", f"--modbus-{request.param}", where,
         "--units", "1,3", "--speedup", "20", "--config", CONFIG, "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    ready = json.loads(proc.stdout.readline() or '{"ok": false}')
    assert ready["ok"] and ready["units"] == [1, 3], proc.stderr.read()
    opts = (["--modbus-tcp", f"127.0.0.1:{ready['port']}"] if request.param == "tcp"
            else ["--modbus-rtu", ready["device"]])
    yield opts
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=10) == 0
    if request.param == "rtu":
        assert not (tmp_path / "bus").exists()      # symlink removed on exit


def test_status_move_jog_json(firmware, heliocal):
    base = ["drive", *firmware, "--unit", "3", "--config", CONFIG, "--timeout", "0.3"]
    code, out, err = heliocal(*base, "status", "--json")
    assert code == 0, err
    assert json.loads(out) == {"unit": 3, "az_steps": 500, "el_steps": 500, "moving": False,
                               "in_position": True, "faults": []}
    code, out, _ = heliocal(*base, "move", "--az-steps", "2500", "--el-steps", "1500", "--wait", "--json")
    assert json.loads(out) == {"ok": True, "az_steps": 2500, "el_steps": 1500, "retries": 0,
                               "outcome": "executed"}
    code, out, _ = heliocal(*base, "jog", "--az-steps", "-500", "--el-steps", "250", "--wait", "--json")
    assert json.loads(out) == {"ok": True, "az_steps": 2000, "el_steps": 1750, "retries": 0,
                               "outcome": "executed"}
    # errors: one JSON line on stdout, nothing on stderr, exit 2 for bad input, 1 for the device
    code, out, err = heliocal(*base, "move", "--az-steps", "80000", "--el-steps", "600", "--json")
    assert code == 2 and err == ""
    assert json.loads(out)["ok"] is False
    assert "az_steps=80000 is outside the soft limits" in json.loads(out)["error"]
    code, out, err = heliocal("drive", *firmware, "--unit", "2", "--config", CONFIG, "--timeout", "0.1",
                              "--retries", "0", "status", "--json")          # unit 2 is not served
    assert code == 1 and err == ""
    assert "unit 2: no answer" in json.loads(out)["error"]
