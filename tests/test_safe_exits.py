"""Ctrl-C and SIGTERM during ``heliocal drive … move --wait``: the axes are stopped, the
command says where, and the firmware (in this process, seen through its own state) agrees."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time

import pytest

from simplant.firmware.physics import AxisParams, SimController
from simplant.firmware.serial import SerialSimFirmware
from tests.conftest import scaled_s


@pytest.fixture
def slow_firmware():
    """One unit at 1x plant speed: a 60,000-step move takes about 40 s."""
    ctl = SimController(1, AxisParams(500, 74800, 0, 75308, speed=1540.0, acceleration=3000.0),
                        AxisParams(500, 68200, 0, 68745, speed=1540.0, acceleration=3000.0))
    fw = SerialSimFirmware({1: ctl})
    fw.start()
    yield fw, ctl
    fw.stop()


def _move(device: str, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "controller.cli", "drive", "--serial", device, "--unit",
                             "1", "move", "--az-steps", "60000", "--el-steps", "60000", "--wait", *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_until_moving(ctl: SimController, p: subprocess.Popen) -> None:
    deadline = time.monotonic() + scaled_s(30)
    while not ctl.status()["moving"]:
        assert p.poll() is None and time.monotonic() < deadline, p.stderr.read() if p.poll() else "timeout"
        time.sleep(0.01)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_during_move_wait_stops_the_axes(slow_firmware, sig):
    fw, ctl = slow_firmware
    p = _move(fw.device)
    _wait_until_moving(ctl, p)
    p.send_signal(sig)
    _, err = p.communicate(timeout=scaled_s(30))
    assert p.returncode == 130, err
    said = re.search(r"unit 1 axes stopped at az (\d+), el (\d+)", err)
    assert said, err
    st = ctl.status()
    assert not st["moving"] and (st["az_steps"], st["el_steps"]) != (60000, 60000)
    assert any(e.command == "STOP" for e in ctl.log)


def test_leave_in_place_leaves_the_axes_moving(slow_firmware):
    fw, ctl = slow_firmware
    p = _move(fw.device, "--leave-in-place")
    _wait_until_moving(ctl, p)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=scaled_s(30))
    assert p.returncode == 130 and "left moving (--leave-in-place)" in err, err
    assert ctl.status()["moving"] and not any(e.command == "STOP" for e in ctl.log)
