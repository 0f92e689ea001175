"""Serial drive against the simulated firmware over a real pty (no mocks of the link)."""

from __future__ import annotations

import random
import time

import pytest
import serial

from controller.devices.drive import ActuatorFault, AxisLimits, DriveLimits, LinkError, NakError
from controller.devices.serial_drive import FirmwareLimitError, SerialBus, SerialDrive
from controller.errors import LimitError
from firmware_proto.codec import Decoder, Frame, encode
from firmware_proto.faults import Reject
from firmware_proto.messages import PAIR, REPLY_BIT, Command, Status
from simplant.firmware.serial import SerialSimFirmware
from tests.conftest import scaled_s

LIMITS = DriveLimits(AxisLimits(500, 74800), AxisLimits(500, 68200))  # as conftest.LIMITS


@pytest.fixture
def bus(firmware):
    b = SerialBus(firmware.device, timeout_s=scaled_s(0.5), retries=2)
    yield b
    b.close()


def test_status_info_limits(bus, firmware):
    d = SerialDrive(bus, 1, LIMITS)
    st = d.status()
    assert (st.az_steps, st.el_steps, st.in_position, st.moving, st.faults) == (500, 500, True, False, ())
    info = d.info()
    assert info.firmware_version == "sim-1.0.0" and info.axes == 2
    assert info.hard_limits == DriveLimits(AxisLimits(0, 75308), AxisLimits(0, 68745))
    assert d.get_limits() == LIMITS
    assert d.ping(b"\x00hello") == b"\x00hello"


def test_move_and_jog_end_exactly_at_target(bus, firmware):
    d = SerialDrive(bus, 2, LIMITS)
    st = d.move_and_wait(12000, 3000, timeout_s=scaled_s(5))
    assert (st.az_steps, st.el_steps) == (12000, 3000)
    d.jog(-250, 40)
    assert d.last_targets == (11750, 3040)
    st = d.wait_in_position(5)
    assert (st.az_steps, st.el_steps) == (11750, 3040)
    ctl = firmware.controllers[2].status()
    assert (ctl["az_steps"], ctl["el_steps"]) == (11750, 3040)
    assert firmware.controllers[1].log == []  # the other unit on the bus saw nothing


def test_two_units_share_one_bus(bus, firmware):
    d1, d2 = SerialDrive(bus, 1, LIMITS), SerialDrive(bus, 2, LIMITS)
    d1.move_abs(2000, 2000)
    d2.move_abs(3000, 1000)
    assert d1.wait_in_position(5).az_steps == 2000
    assert d2.wait_in_position(5).az_steps == 3000


def test_out_of_range_never_sent(bus, firmware):
    d = SerialDrive(bus, 1, LIMITS)
    d.status()  # session-start PING + one status
    requests = firmware.stats["requests"]
    with pytest.raises(LimitError, match="az_steps=74801"):
        d.move_abs(74801, 1000)
    assert firmware.stats["requests"] == requests
    with pytest.raises(LimitError, match="el_steps=499"):
        d.jog(0, -1)  # from el target 500
    assert firmware.stats["requests"] == requests + 1  # only the status read for the jog check
    assert [e.command for e in firmware.controllers[1].log] == []


def test_firmware_refuses_out_of_range_too(bus, firmware):
    """A drive whose own limits are wider still cannot move outside: NAK OUT_OF_RANGE -> exit 2."""
    wide = DriveLimits(AxisLimits(0, 75308), AxisLimits(0, 68745))
    d = SerialDrive(bus, 1, wide)
    with pytest.raises(FirmwareLimitError, match="OUT_OF_RANGE") as info:
        d.move_abs(75000, 1000)
    assert info.value.code == Reject.OUT_OF_RANGE and info.value.exit_code == 2
    assert d.status().az_target == 500


def test_fault_blocks_motion_until_cleared(bus, firmware):
    d = SerialDrive(bus, 1, LIMITS)
    d.move_abs(30000, 500)
    time.sleep(0.02)
    firmware.controllers[1].inject_stall("az")
    with pytest.raises(ActuatorFault) as info:
        d.wait_in_position(2)
    assert info.value.faults == ["stall_az"]
    with pytest.raises(NakError, match="FAULT_ACTIVE") as nak:
        d.move_abs(1000, 1000)
    assert nak.value.code == Reject.FAULT_ACTIVE
    d.clear_fault()
    assert d.move_and_wait(1000, 1000, timeout_s=scaled_s(5)).az_steps == 1000


def test_set_limits_outside_hard_range_refused(bus):
    d = SerialDrive(bus, 1, LIMITS)
    with pytest.raises(FirmwareLimitError, match="BAD_LIMITS"):
        d.set_limits(DriveLimits(AxisLimits(-5, 100), AxisLimits(500, 600)))
    d.set_limits(DriveLimits(AxisLimits(500, 2000), AxisLimits(500, 600)))
    assert d.get_limits() == DriveLimits(AxisLimits(500, 2000), AxisLimits(500, 600))
    # the axes stand at 500: limits starting at 1000 would leave them outside -> refused, unchanged
    with pytest.raises(FirmwareLimitError, match="BAD_LIMITS"):
        d.set_limits(DriveLimits(AxisLimits(1000, 2000), AxisLimits(500, 600)))
    assert d.get_limits() == DriveLimits(AxisLimits(500, 2000), AxisLimits(500, 600))


def test_set_limits_refused_during_a_move(bus, firmware):
    """Limits cannot change under a running move: the axis would end outside them."""
    d = SerialDrive(bus, 1, LIMITS)
    d.move_abs(60000, 60000)
    with pytest.raises(NakError, match="BUSY"):
        d.set_limits(DriveLimits(AxisLimits(500, 40000), AxisLimits(500, 40000)))
    st = d.wait_in_position(scaled_s(10))
    assert (st.az_steps, st.el_steps) == (60000, 60000)
    assert firmware.controllers[1].az.soft_max == LIMITS.az.max_steps


def test_unserved_address_times_out_with_link_error(bus):
    d = SerialDrive(bus, 9, LIMITS)
    expected = rf"unit 9: no valid reply to PING .* after 3 attempts of {bus.timeout_s:g} s"
    with pytest.raises(LinkError, match=expected):
        d.status()
    assert bus.retries_used == 2  # the first attempt plus retries=2 retransmissions


def test_firmware_gone_is_a_link_error(make_ctl):
    fw = SerialSimFirmware({1: make_ctl(1)})
    fw.start()
    b = SerialBus(fw.device, timeout_s=scaled_s(0.1), retries=1)
    d = SerialDrive(b, 1, LIMITS)
    d.status()
    fw.stop()
    with pytest.raises(LinkError):
        d.status()
    b.close()


def _raw_exchange(port: serial.Serial, wire: bytes, expect: int, timeout: float = 1.0) -> list[Frame]:
    port.write(wire)
    dec, got = Decoder(), []
    deadline = time.monotonic() + timeout
    while len(got) < expect and time.monotonic() < deadline:
        got += dec.feed(port.read(256))
    return got


def test_duplicate_jog_is_answered_not_executed(firmware):
    """The same JOG frame twice on the wire (a retransmission): one execution, two equal replies."""
    port = serial.Serial(firmware.device, 115200, timeout=scaled_s(0.05))
    jog = encode(Frame(1, 42, Command.JOG, PAIR.pack(100, 0)))
    replies = _raw_exchange(port, jog + jog, expect=2)
    port.close()
    assert len(replies) == 2 and replies[0] == replies[1]
    assert replies[0].command == Command.JOG | REPLY_BIT and replies[0].payload[0] == Reject.OK
    assert PAIR.unpack(replies[0].payload[1:]) == (600, 500)
    jogs = [e for e in firmware.controllers[1].log if e.command == "JOG"]
    assert len(jogs) == 1 and firmware.stats["duplicates"] == 1


def test_power_cycle_forgets_cache_and_refuses_the_retry(firmware):
    """After a power cycle the retransmitted JOG is not answered from the (lost) cache; it is
    refused with FAULT_ACTIVE, so it still runs only once."""
    frame = Frame(1, 7, Command.JOG, PAIR.pack(300, 0))
    first = firmware.handle(frame)
    firmware.power_cycle(1)
    again = firmware.handle(frame)
    assert first != again
    assert Frame(1, 7, Command.JOG | REPLY_BIT, bytes([Reject.FAULT_ACTIVE])) == Decoder().feed(again)[0]
    assert [(e.command, e.result) for e in firmware.controllers[1].log] == [
        ("JOG", Reject.OK), ("POWER_CYCLE", Reject.OK), ("JOG", Reject.FAULT_ACTIVE)]


def test_session_start_ping_defeats_stale_cache(firmware):
    """A new bus session must not get a cached reply from an earlier session with the same seq."""
    b1 = SerialBus(firmware.device, timeout_s=scaled_s(0.5), retries=0)
    SerialDrive(b1, 1, LIMITS).stop()
    b1.close()
    for _ in range(3):
        b2 = SerialBus(firmware.device, timeout_s=scaled_s(0.5), retries=0)
        SerialDrive(b2, 1, LIMITS).stop()
        b2.close()
    assert [e.command for e in firmware.controllers[1].log] == ["STOP"] * 4
    assert firmware.stats["duplicates"] == 0


def test_nak_for_unknown_command_and_bad_length(firmware):
    port = serial.Serial(firmware.device, 115200, timeout=scaled_s(0.05))
    got = _raw_exchange(port, encode(Frame(2, 1, 0x55)) + encode(Frame(2, 2, Command.MOVE_ABS, b"\x01")),
                        expect=2)
    port.close()
    assert [(f.command, f.payload) for f in got] == [
        (0x55 | REPLY_BIT, bytes([Reject.UNKNOWN_COMMAND])),
        (Command.MOVE_ABS | REPLY_BIT, bytes([Reject.BAD_LENGTH]))]


def test_garbage_before_request_is_skipped(firmware):
    port = serial.Serial(firmware.device, 115200, timeout=scaled_s(0.05))
    garbage = random.Random(5).randbytes(40).replace(b"\x00", b"\x01")
    got = _raw_exchange(port, garbage + encode(Frame(1, 3, Command.GET_STATUS)), expect=1)
    port.close()
    assert len(got) == 1 and Status.unpack(got[0].payload[1:]).az_steps == 500
    assert firmware.stats["rejected_crc"] + firmware.stats["rejected_cobs"] \
        + firmware.stats["rejected_short"] + firmware.stats["rejected_length"] == 1


def test_bus_reopens_after_firmware_restart(make_ctl, tmp_path):
    """The firmware process restarts on a new pty behind the same symlink: one LinkError,
    then the bus reopens by name and works (with a new session-start PING)."""
    link = str(tmp_path / "bus")
    fw = SerialSimFirmware({1: make_ctl(1)}, link)
    fw.start()
    b = SerialBus(link, timeout_s=scaled_s(0.05), retries=1)
    d = SerialDrive(b, 1, LIMITS)
    d.move_and_wait(3000, 3000, timeout_s=scaled_s(5))
    fw.stop()
    with pytest.raises(LinkError, match="lost|no valid reply"):
        d.status()
    with pytest.raises(LinkError, match="cannot open"):
        d.status()  # nothing behind the link yet
    fw2 = SerialSimFirmware({1: make_ctl(1)}, link)
    fw2.start()
    try:
        assert d.status().az_steps == 500  # the restarted controller
        assert fw2.stats["duplicates"] == 0
    finally:
        b.close()
        fw2.stop()


@pytest.mark.parametrize("inject, faults", [
    (lambda fw: fw.controllers[1].inject_limit_hit("el"), ["limit_el"]),
    (lambda fw: fw.power_cycle(1), ["power_cycle"]),
])
def test_fault_mid_move_is_reported(bus, firmware, inject, faults):
    d = SerialDrive(bus, 1, LIMITS)
    d.move_abs(60000, 60000)
    time.sleep(0.03)
    inject(firmware)
    with pytest.raises(ActuatorFault) as info:
        d.wait_in_position(3)
    assert info.value.faults == faults
    assert not d.status().in_position  # latched until cleared
    d.clear_fault()
    assert d.move_and_wait(1000, 1000, timeout_s=scaled_s(5)).el_steps == 1000


def test_a_command_the_firmware_cannot_execute_is_nakd_and_serving_goes_on():
    """A hard range beyond the int32 wire type (a config the controller refuses, see
    tests/test_config.py) must not kill the firmware: GET_INFO gets NAK INTERNAL, the next
    request is served."""
    from simplant.firmware.physics import AxisParams, SimController
    from simplant.firmware.serial import SerialSimFirmware

    huge = AxisParams(500, 74800, 0, 5_000_000_000, speed=1540.0, acceleration=3000.0)
    fw = SerialSimFirmware({1: SimController(1, huge, huge)})
    fw.start()
    try:
        port = serial.Serial(fw.device, 115200, timeout=scaled_s(0.05))
        wire = encode(Frame(1, 1, Command.GET_INFO)) + encode(Frame(1, 2, Command.GET_STATUS))
        got = _raw_exchange(port, wire, expect=2, timeout=scaled_s(2))
        port.close()
        assert [(f.seq, f.payload[:1]) for f in got] == [(1, bytes([Reject.INTERNAL])),
                                                         (2, bytes([Reject.OK]))]
        assert fw.stats["internal_errors"] == 1 and "0x" in fw.last_error
    finally:
        fw.stop()
