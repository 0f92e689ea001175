"""Interoperability with an independent Modbus client: mbpoll (libmodbus).

mbpoll reads the actual-position registers at the addresses in registers.yaml and writes a
target and the MOVE command; the results are checked against ModbusDrive.status() and
against ``heliocal drive --modbus-tcp ... status --json``."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from controller.devices.modbus_drive import ModbusDrive
from firmware_proto.registers import load_register_map
from tests.conftest import scaled_s

from .conftest import LIMITS

MBPOLL = shutil.which("mbpoll")
REPO = Path(__file__).resolve().parents[2]
MAP = load_register_map()

# The reason is printed in pytest's short summary (-ra is in addopts).
pytestmark = pytest.mark.skipif(MBPOLL is None, reason="mbpoll is not installed "
                                "(Debian package mbpoll: apt-get install mbpoll)")


def mbpoll(port: int, unit: int, *args: str, values: tuple[int, ...] = ()) -> subprocess.CompletedProcess:
    """``mbpoll [options] host [values]``; negative values follow ``--``."""
    return subprocess.run([MBPOLL, "-m", "tcp", "-p", str(port), "-a", str(unit), "-0", "-o", "1",
                           *args, "--", "127.0.0.1", *map(str, values)],
                          capture_output=True, text=True, timeout=10)


def read_int32(port: int, unit: int, name: str) -> int:
    reg = MAP[name]
    assert reg.type == "int32" and reg.table == "input"
    flags = ["-B"] if reg.word_order == "big" else []
    out = mbpoll(port, unit, "-1", "-t", "3:int", *flags, "-r", str(reg.address), "-c", "1")
    assert out.returncode == 0, out.stderr
    m = re.search(rf"^\[{reg.address}\]:\s+(-?\d+)\s*$", out.stdout, re.M)
    assert m, out.stdout
    return int(m[1])


def write_holding(port: int, unit: int, name: str, *values: int) -> subprocess.CompletedProcess:
    reg = MAP[name]
    kind = "4:int" if reg.type == "int32" else "4"
    flags = ["-B"] if reg.count == 2 and reg.word_order == "big" else []
    return mbpoll(port, unit, "-t", kind, *flags, "-r", str(reg.address), values=values)


def cli_status(capsys, port: int, unit: int) -> dict:
    """``heliocal drive --modbus-tcp 127.0.0.1:PORT --unit N status --json``, in this process."""
    from controller.cli import main

    capsys.readouterr()
    code = main(["drive", "--modbus-tcp", f"127.0.0.1:{port}", "--unit", str(unit),
                 "--config", str(REPO / "configs/demo.yaml"), "status", "--json"])
    out = capsys.readouterr()
    assert code == 0, out.out + out.err
    return json.loads(out.out)


def test_mbpoll_reads_what_the_drive_reads(sim, link):
    for unit in (1, 2):
        st = ModbusDrive(link, unit, LIMITS).status()
        az = read_int32(sim.port, unit, "az_actual_steps")
        el = read_int32(sim.port, unit, "el_actual_steps")
        assert (az, el) == (st.az_steps, st.el_steps) == ((500, 500) if unit == 1 else (1000, 2000))


def test_mbpoll_moves_the_actuator(sim, link, controllers, capsys):
    assert write_holding(sim.port, 2, "az_target_steps", 4321).returncode == 0
    assert write_holding(sim.port, 2, "el_target_steps", 2468).returncode == 0
    out = write_holding(sim.port, 2, "command", MAP.code("command", "move"))
    assert out.returncode == 0, out.stderr
    st = ModbusDrive(link, 2, LIMITS).wait_in_position(scaled_s(10))
    assert (st.az_steps, st.el_steps) == (4321, 2468)
    assert controllers[2].log[-1].command == "MOVE_ABS" and controllers[2].log[-1].args == (4321, 2468)
    assert (read_int32(sim.port, 2, "az_actual_steps"), read_int32(sim.port, 2, "el_actual_steps")) == (
        4321, 2468)
    assert cli_status(capsys, sim.port, 2) == {"unit": 2, "az_steps": 4321, "el_steps": 2468,
                                       "moving": False, "in_position": True, "faults": []}


def test_mbpoll_negative_jog(sim, link, controllers):
    """A negative int32 written by mbpoll (-B: high word first) arrives as the same number."""
    assert write_holding(sim.port, 2, "jog_az_steps", -21).returncode == 0
    assert write_holding(sim.port, 2, "jog_el_steps", -300).returncode == 0
    assert write_holding(sim.port, 2, "command", MAP.code("command", "jog")).returncode == 0
    assert controllers[2].log[-1].command == "JOG" and controllers[2].log[-1].args == (-21, -300)
    st = ModbusDrive(link, 2, LIMITS).wait_in_position(scaled_s(10))
    assert (st.az_steps, st.el_steps) == (1000 - 21, 2000 - 300)


def test_mbpoll_out_of_range_target_is_refused(sim, controllers):
    out = write_holding(sim.port, 1, "az_target_steps", 74801)   # soft max 74800
    assert out.returncode != 0
    assert "Illegal data value" in out.stdout + out.stderr
    assert write_holding(sim.port, 1, "command", MAP.code("command", "move")).returncode == 0
    assert controllers[1].log[-1].args == (500, 500)              # the old setpoints


def test_mbpoll_over_rtu_pty(sim, tmp_path):
    """Same registers through libmodbus' RTU framing, on the simulator's pty."""
    device = sim.start_rtu(str(tmp_path / "rs485"))
    reg = MAP["el_actual_steps"]
    out = subprocess.run([MBPOLL, "-m", "rtu", "-b", "115200", "-P", "none", "-a", "2", "-0", "-1",
                          "-o", "1", "-t", "3:int", "-B", "-r", str(reg.address), "-c", "1", device],
                         capture_output=True, text=True, timeout=10)
    assert out.returncode == 0, out.stderr
    assert re.search(rf"^\[{reg.address}\]:\s+2000\s*$", out.stdout, re.M), out.stdout
