"""CLI contract of ``heliocal sim firmware --serial-link`` and ``heliocal drive --serial``."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from controller.cli import main
from simplant.firmware.physics import AxisParams, SimController
from simplant.firmware.serial import SerialSimFirmware

ROOT = Path(__file__).resolve().parents[2]
CONFIG = str(ROOT / "configs" / "demo.yaml")
CLI = [sys.executable, "-m", "controller.cli"]


def heliocal_process(*args: str, timeout: float = 60) -> tuple[int, dict | None, str]:
    """Run the real console entry point in a child process."""
    run = subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    assert "Traceback" not in run.stderr, run.stderr
    out = run.stdout.strip().splitlines()
    return run.returncode, (json.loads(out[-1]) if out else None), run.stderr


@pytest.fixture
def heliocal(capsys):
    """Run ``heliocal`` in this process (the CLI's start-up imports cost seconds per child)."""

    def run(*args: str) -> tuple[int, dict | None, str]:
        rc = main(list(args))  # any exception other than SystemExit would fail the test here
        captured = capsys.readouterr()
        out = captured.out.strip().splitlines()
        return rc, (json.loads(out[-1]) if out else None), captured.err

    return run


@pytest.fixture
def sim_process(tmp_path):
    link = tmp_path / "buses" / "bus1"
    proc = subprocess.Popen([*CLI, "sim", "firmware", "--serial-link", str(link), "--units", "1,2",
                             "--config", CONFIG, "--speedup", "100", "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    ready = json.loads(proc.stdout.readline())
    yield proc, link, ready
    if proc.poll() is None:
        proc.kill()
        proc.wait()


def test_sim_firmware_and_drive_contract(sim_process, heliocal):
    proc, link, ready = sim_process
    assert ready["ok"] is True and ready["units"] == [1, 2] and ready["link"] == str(link)
    assert os.readlink(link) == ready["device"]
    drive = ["drive", "--serial", str(link), "--config", CONFIG]

    rc, out, _ = heliocal_process(*drive, "--unit", "1", "status", "--json")
    assert rc == 0
    assert out == {"unit": 1, "az_steps": 500, "el_steps": 500, "moving": False, "in_position": True,
                   "faults": []}

    rc, out, _ = heliocal(*drive, "--unit", "2", "move", "--az-steps", "3000", "--el-steps", "2000",
                          "--wait", "--json")
    assert (rc, out) == (0, {"ok": True, "az_steps": 3000, "el_steps": 2000, "retries": 0,
                             "outcome": "executed"})

    rc, out, _ = heliocal(*drive, "--unit", "2", "jog", "--az-steps", "-250", "--el-steps", "75",
                          "--wait", "--json")
    assert (rc, out) == (0, {"ok": True, "az_steps": 2750, "el_steps": 2075, "retries": 0,
                             "outcome": "executed"})

    # Out of range (demo.yaml azimuth soft limits 500..74800): exit 2, nothing moved.
    rc, out, _ = heliocal(*drive, "--unit", "2", "move", "--az-steps", "74801", "--el-steps", "2000",
                          "--json")
    assert rc == 2 and out["ok"] is False and "az_steps=74801" in out["error"]
    rc, out, _ = heliocal(*drive, "--unit", "2", "jog", "--az-steps", "0", "--el-steps", "-1576",
                          "--json")
    assert rc == 2 and "el_steps=499" in out["error"]
    rc, out, _ = heliocal(*drive, "--unit", "2", "status", "--json")
    assert (out["az_steps"], out["el_steps"]) == (2750, 2075)

    # A unit nobody serves: a clear link error, exit 1.
    rc, out, _ = heliocal(*drive, "--unit", "5", "--timeout", "0.05", "--retries", "1", "status", "--json")
    assert rc == 1 and out["ok"] is False and "unit 5: no valid reply" in out["error"]

    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=5) == 0
    assert not os.path.lexists(link)


@pytest.mark.parametrize("args, message", [
    (["--unit", "300", "status"], "--unit"),
    (["--unit", "1", "--timeout", "0", "status"], "--timeout"),
    (["--unit", "1", "--config", "/nonexistent.yaml", "status"], "/nonexistent.yaml"),
])
def test_bad_input_exits_2(heliocal, args, message):
    rc, out, _ = heliocal("drive", "--serial", "/dev/null-not-there", *args, "--json")
    assert rc == 2 and out["ok"] is False and message in out["error"]


def test_sim_firmware_bad_units(heliocal, tmp_path):
    rc, _, err = heliocal("sim", "firmware", "--serial-link", str(tmp_path / "x"), "--units", "1,abc")
    assert rc == 2 and "'abc'" in err and not (tmp_path / "x").exists()


def test_firmware_limits_are_checked_too(heliocal, tmp_path):
    """Config allows az up to 74800 but the firmware only 10000: refused before sending."""
    ctl = SimController(1, AxisParams(500, 10000, 0, 75308), AxisParams(500, 68200, 0, 68745))
    fw = SerialSimFirmware({1: ctl}, str(tmp_path / "bus"))
    fw.start()
    try:
        rc, out, _ = heliocal("drive", "--serial", str(tmp_path / "bus"), "--unit", "1", "--config", CONFIG,
                              "move", "--az-steps", "20000", "--el-steps", "600", "--json")
    finally:
        fw.stop()
    assert rc == 2 and "(firmware)" in out["error"] and "az_steps=20000" in out["error"]
    assert [e.command for e in ctl.log] == []


def test_drive_cli_same_contract_over_modbus_tcp(heliocal):
    """``drive --modbus-tcp`` goes through the same LinkPool path and prints the same JSON."""
    modbus_sim = pytest.importorskip("simplant.firmware.modbus", reason="Modbus simulator not present")
    ctl = SimController(3, AxisParams(500, 74800, 0, 75308, speed=50000, acceleration=100000),
                        AxisParams(500, 68200, 0, 68745, speed=50000, acceleration=100000))
    server = modbus_sim.ModbusSimServer({3: ctl})
    port = server.start_tcp("127.0.0.1", 0)
    try:
        drive = ["drive", "--modbus-tcp", f"127.0.0.1:{port}", "--unit", "3", "--config", CONFIG]
        rc, out, _ = heliocal(*drive, "jog", "--az-steps", "1000", "--el-steps", "20", "--wait", "--json")
        assert (rc, out) == (0, {"ok": True, "az_steps": 1500, "el_steps": 520, "retries": 0,
                                 "outcome": "executed"})
        rc, out, _ = heliocal(*drive, "status", "--json")
        assert out == {"unit": 3, "az_steps": 1500, "el_steps": 520, "moving": False, "in_position": True,
                       "faults": []}
        rc, out, _ = heliocal(*drive, "move", "--az-steps", "400", "--el-steps", "520", "--json")
        assert rc == 2 and "az_steps=400" in out["error"]
    finally:
        server.stop()
    assert [e.command for e in ctl.log] == ["JOG"]
