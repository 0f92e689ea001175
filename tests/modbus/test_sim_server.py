"""The simulated Modbus actuator on the wire, through a plain pymodbus client: register
contents, exception codes (MODBUS.md), several units, TCP and RTU in one process."""

from __future__ import annotations

import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ModbusIOException

from firmware_proto.faults import Fault, Reject
from simplant.firmware.modbus import ModbusSimServer
from tests.conftest import scaled_s

from .conftest import make_controller


def _exc(rr) -> int | None:
    return rr.exception_code if rr.isError() else None


def test_input_registers_at_rest(raw_client):
    rr = raw_client.read_input_registers(0, count=17, device_id=2)
    assert not rr.isError()
    r = rr.registers
    # unit 2 starts at (1000, 2000): int32 big-endian -> [0, 1000], [0, 2000]
    assert r[0:4] == [0, 1000, 0, 2000]
    assert r[4:8] == [0, 1000, 0, 2000]        # active targets = position
    assert r[8] == 0b00010                     # in_position only
    assert r[9] == 0 and r[10] == 0 and r[11] == 0
    assert r[12] == 0x4843                     # 'HC'
    assert r[13:17] == [1, 0, 0, 1]            # firmware "sim-1.0.0", map version 1
    hard = raw_client.read_input_registers(17, count=8, device_id=2).registers
    assert hard == [0, 0, 1, 75308 - 65536, 0, 0, 1, 68745 - 65536]   # 75308 = 0x0001_266C


def test_move_through_registers(raw_client, controllers):
    assert _exc(raw_client.write_registers(0, [0, 3000, 0, 600], device_id=1)) is None
    assert raw_client.read_holding_registers(0, count=4, device_id=1).registers == [0, 3000, 0, 600]
    assert _exc(raw_client.write_register(8, 1, device_id=1)) is None
    r = raw_client.read_input_registers(0, count=12, device_id=1).registers
    assert r[4:8] == [0, 3000, 0, 600] and r[8] & 1  # driving to the new target, moving
    assert r[11] == 1                                 # one command executed
    deadline = time.monotonic() + 5
    while raw_client.read_input_registers(8, count=1, device_id=1).registers[0] != 0b10:
        assert time.monotonic() < deadline
        time.sleep(0.02)
    assert raw_client.read_input_registers(0, count=4, device_id=1).registers == [0, 3000, 0, 600]
    assert [e.command for e in controllers[1].log] == ["MOVE_ABS"]


def test_out_of_range_target_is_refused_and_not_stored(raw_client, sim, controllers):
    rr = raw_client.write_registers(0, [0, 499, 0, 600], device_id=1)   # az soft min is 500
    assert _exc(rr) == 3
    assert raw_client.read_holding_registers(0, count=4, device_id=1).registers == [0, 500, 0, 500]
    # a MOVE afterwards uses the old setpoints: the refused value never reaches the physics
    assert _exc(raw_client.write_register(8, 1, device_id=1)) is None
    assert controllers[1].log[-1].args == (500, 500)
    assert sim.writes[0].exception == 3 and sim.writes[0].decoded["az_target_steps"] == 499


def test_negative_target_word_order(raw_client):
    # -5 as int32 big-endian is [0xFFFF, 0xFFFB]: below the soft minimum -> exception 3
    assert _exc(raw_client.write_registers(2, [0xFFFF, 0xFFFB], device_id=1)) == 3


def test_jog_out_of_range_rejected_with_reason(raw_client, controllers):
    assert _exc(raw_client.write_registers(4, [0xFFFF, 0xFF9C, 0, 0], device_id=1)) is None  # -100
    assert _exc(raw_client.write_register(8, 6, device_id=1)) == 3    # 500 - 100 < 500
    assert raw_client.read_input_registers(10, count=2, device_id=1).registers == [
        Reject.OUT_OF_RANGE, 0]
    assert controllers[1].status()["az_target"] == 500


@pytest.mark.parametrize(("call", "code"), [
    (lambda c: c.read_input_registers(25, count=1, device_id=1), 2),      # beyond the map
    (lambda c: c.read_holding_registers(15, count=4, device_id=1), 2),
    (lambda c: c.write_register(1, 7, device_id=1), 2),                   # half an int32
    (lambda c: c.write_registers(1, [0, 7], device_id=1), 2),             # straddles two int32
    (lambda c: c.read_coils(0, count=1, device_id=1), 1),
    (lambda c: c.write_register(8, 99, device_id=1), 3),                  # unknown command
])
def test_exception_codes(raw_client, call, code):
    assert _exc(call(raw_client)) == code


def test_fault_blocks_motion_with_exception_4(raw_client, controllers):
    controllers[1].inject_stall("el")
    r = raw_client.read_input_registers(8, count=2, device_id=1).registers
    assert r == [0b10000, Fault.STALL_EL]                    # fault bit, not in position
    assert _exc(raw_client.write_register(8, 3, device_id=1)) == 4      # HOME refused
    assert raw_client.read_input_registers(10, count=1, device_id=1).registers == [Reject.FAULT_ACTIVE]
    assert _exc(raw_client.write_register(8, 5, device_id=1)) is None   # CLEAR_FAULT
    assert raw_client.read_input_registers(8, count=2, device_id=1).registers == [0b10, 0]


def test_soft_limits_read_write_busy(raw_client, controllers):
    assert raw_client.read_holding_registers(9, count=8, device_id=1).registers == [
        0, 500, 1, 74800 - 65536, 0, 500, 1, 68200 - 65536]
    # narrow azimuth to [500, 70000]: 70000 = 0x0001_1170
    assert _exc(raw_client.write_registers(9, [0, 500, 1, 0x1170], device_id=1)) is None
    assert (controllers[1].az.soft_min, controllers[1].az.soft_max) == (500, 70000)
    # a minimum above the axis's position (500) would leave it outside its range -> 3, unchanged
    assert _exc(raw_client.write_registers(9, [0, 600, 1, 0x1170], device_id=1)) == 3
    assert (controllers[1].az.soft_min, controllers[1].az.soft_max) == (500, 70000)
    # a refused request stores nothing: limits written together with a bad command are not kept
    assert _exc(raw_client.write_registers(8, [99, 0, 500, 0, 1000], device_id=1)) is not None
    assert (controllers[1].az.soft_min, controllers[1].az.soft_max) == (500, 70000)
    # max beyond the hard range (75308) -> 3
    assert _exc(raw_client.write_registers(11, [1, 0x3000], device_id=1)) == 3   # 77824
    # busy while moving
    raw_client.write_registers(0, [0, 9000, 0, 9000], device_id=1)
    raw_client.write_register(8, 1, device_id=1)
    assert _exc(raw_client.write_registers(13, [0, 700], device_id=1)) == 6
    assert controllers[1].el.soft_min == 500


def test_unknown_unit_never_answers(raw_client):
    with pytest.raises(ModbusIOException):
        raw_client.read_input_registers(0, count=1, device_id=9)
    # the connection still serves the real units afterwards
    assert not raw_client.read_input_registers(0, count=1, device_id=1).isError()


def test_silent_unit_hook(raw_client, sim):
    sim.silent_units.add(2)
    with pytest.raises(ModbusIOException):
        raw_client.read_input_registers(0, count=1, device_id=2)
    sim.silent_units.clear()
    assert not raw_client.read_input_registers(0, count=1, device_id=2).isError()


def test_tcp_and_rtu_share_units_and_stop_independently(sim, raw_client, tmp_path):
    link = tmp_path / "bus"
    dev = sim.start_rtu(str(link))
    assert dev == str(link) and link.is_symlink()
    rtu = ModbusSerialClient(dev, baudrate=115200, timeout=scaled_s(0.3), retries=0)
    try:
        raw_client.write_registers(0, [0, 1234, 0, 4321], device_id=1)
        assert rtu.read_holding_registers(0, count=4, device_id=1).registers == [0, 1234, 0, 4321]
        sim.pause("tcp")      # stopping one server must not stop the other (no class-global stop)
        assert rtu.read_input_registers(0, count=4, device_id=2).registers == [0, 1000, 0, 2000]
        sim.resume("tcp")
        raw_client.close()
        assert not raw_client.read_input_registers(0, count=1, device_id=1).isError()
    finally:
        rtu.close()
    sim.stop()
    assert not link.exists()


def test_two_servers_in_one_process():
    a = ModbusSimServer({1: make_controller(1)})
    b = ModbusSimServer({1: make_controller(1, (700, 800))})
    try:
        pa, pb = a.start_tcp(), b.start_tcp()
        a.stop()
        client = ModbusTcpClient("127.0.0.1", port=pb, timeout=scaled_s(0.3), retries=0)
        assert client.read_input_registers(0, count=4, device_id=1).registers == [0, 700, 0, 800]
        client.close()
        assert not ModbusTcpClient("127.0.0.1", port=pa, timeout=scaled_s(0.3), retries=0).connect()
    finally:
        a.stop()
        b.stop()


def test_rejects_bad_unit_ids():
    with pytest.raises(ValueError, match="1..247"):
        ModbusSimServer({0: make_controller(0)})


def test_targets_and_command_in_one_request(raw_client, controllers):
    # FC 16 over holding 0..8: targets, jog deltas, MOVE -> executed with the new targets
    assert _exc(raw_client.write_registers(0, [0, 2000, 0, 1500, 0, 0, 0, 0, 1], device_id=1)) is None
    assert controllers[1].log[-1].command == "MOVE_ABS" and controllers[1].log[-1].args == (2000, 1500)
    # refused command (fault latched): the setpoints of that request are not stored either
    controllers[1].inject_stall("az")
    assert _exc(raw_client.write_registers(0, [0, 3000, 0, 3000, 0, 0, 0, 0, 1], device_id=1)) == 4
    assert raw_client.read_holding_registers(0, count=4, device_id=1).registers == [0, 2000, 0, 1500]


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(address=st.integers(0, 16), words=st.lists(st.integers(0, 0xFFFF), min_size=1, max_size=9),
       command=st.sampled_from([1, 6]))
def test_random_writes_never_drive_out_of_range(raw_client, controllers, address, words, command):
    """Whatever a master writes, every request is answered (normally or with a documented
    exception code) and a MOVE/JOG the physics executes has its target inside the soft limits."""
    words = words[:17 - address]
    c = controllers[1]
    n_log = len(c.log)
    for rr in (raw_client.write_registers(address, words, device_id=1),
               raw_client.write_register(8, command, device_id=1)):
        assert _exc(rr) in (None, 2, 3, 4, 6)
    st_ = c.status()
    assert c.az.hard_min <= c.az.soft_min < c.az.soft_max <= c.az.hard_max
    assert c.el.hard_min <= c.el.soft_min < c.el.soft_max <= c.el.hard_max
    executed = [e for e in c.log[n_log:] if e.command in ("MOVE_ABS", "JOG") and e.result == Reject.OK]
    if executed:
        assert c.az.soft_min <= st_["az_target"] <= c.az.soft_max
        assert c.el.soft_min <= st_["el_target"] <= c.el.soft_max
    c.stop()


def test_port_in_use_and_path_taken_are_clear_oserrors(sim, tmp_path):
    other = ModbusSimServer({1: make_controller(1)})
    try:
        with pytest.raises(OSError, match=f"cannot listen on 127.0.0.1:{sim.port}: Address already in use"):
            other.start_tcp(port=sim.port)
        taken = tmp_path / "file"
        taken.write_text("")
        with pytest.raises(FileExistsError, match="exists and is not a symlink"):
            other.start_rtu(str(taken))
        assert taken.read_text() == ""
    finally:
        other.stop()
