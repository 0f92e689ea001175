"""A long outage on the serial line: no jog may be lost to the sequence number wrapping, and a
command whose answer never came is reported as of unknown outcome, never as a failure."""

from __future__ import annotations

import json

from controller.cli import main
from controller.devices.drive import LinkError
from controller.devices.serial_drive import SerialBus, SerialDrive
from tests.conftest import scaled_s


def test_jog_after_255_failed_requests_is_executed(firmware, noisy_line_factory, limits):
    """255 requests fail during the outage, so the 8-bit sequence number comes round to the one
    of the last executed JOG: a new JOG with the same bytes must still be executed."""
    line = noisy_line_factory(1, drop=0.0, flip=0.0, dup=0.0, delay=0.0)
    bus = SerialBus(line.device, timeout_s=scaled_s(0.004), retries=0)
    drive = SerialDrive(bus, 1, limits)
    bus.timeout_s = scaled_s(0.5)
    drive._send_jog(100, 0)
    bus.timeout_s = scaled_s(0.004)
    line.cut()
    for _ in range(255):
        try:
            drive.status()
        except LinkError:
            continue
        raise AssertionError("the cut line answered")
    line.restore()
    bus.timeout_s = scaled_s(0.5)
    drive._send_jog(100, 0)
    jogs = [e for e in firmware.controllers[1].log if e.command == "JOG"]
    assert len(jogs) == 2
    assert drive.status().az_target == 500 + 200


def test_no_answer_is_outcome_unknown_in_the_json(firmware, noisy_line_factory, capsys):
    line = noisy_line_factory(2, drop=0.0, flip=0.0, dup=0.0, delay=0.0)
    line.cut()
    rc = main(["drive", "--serial", line.device, "--unit", "1", "--timeout", str(scaled_s(0.02)),
               "--retries", "1", "jog", "--az-steps", "10", "--el-steps", "0", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 1 and out["ok"] is False and out["outcome"] == "unknown"
    line.restore()
    rc = main(["drive", "--serial", line.device, "--unit", "1", "jog", "--az-steps", "10", "--el-steps", "0",
               "--json"])
    assert rc == 0 and json.loads(capsys.readouterr().out)["outcome"] == "executed"


def test_refused_and_out_of_range_are_not_executed(firmware, capsys):
    rc = main(["drive", "--serial", firmware.device, "--unit", "1", "move", "--az-steps", "99999999",
               "--el-steps", "600", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 2 and out["outcome"] == "not_executed"
    assert not [e for e in firmware.controllers[1].log if e.command == "MOVE_ABS"]
