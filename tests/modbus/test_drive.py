"""ModbusDrive over TCP and RTU against the simulated actuator: the Drive contract, limit
checks before sending, exception responses, silent units, a server that stops mid-move,
read-back verification and lost command answers."""

from __future__ import annotations

import socket
import threading
import time

import pytest

from controller.devices.drive import (
    ActuatorFault,
    AxisLimits,
    DriveError,
    DriveLimits,
    LinkError,
    NakError,
)
from controller.devices.factory import LinkPool
from controller.devices.modbus_drive import (
    ModbusDrive,
    ModbusExceptionError,
    ModbusLimitError,
    ModbusLink,
)
from controller.errors import LimitError
from controller.link_config import ModbusRtuLink, ModbusTcpLink
from firmware_proto.faults import Reject
from tests.conftest import scaled_s

from .conftest import LIMITS


def _targets_sent(sim) -> list[dict]:
    return [w.decoded for w in sim.writes if "az_target_steps" in w.decoded]


def test_status_matches_controller(drive, controllers):
    st = drive.status()
    assert (st.unit, st.az_steps, st.el_steps, st.az_target, st.el_target) == (1, 500, 500, 500, 500)
    assert st.in_position and not st.moving and st.faults == ()
    assert ModbusDrive(drive.link, 2, LIMITS).status().el_steps == 2000


def test_info_and_limits(drive, controllers):
    info = drive.info()
    assert (info.firmware_version, info.protocol_version, info.axes) == ("1.0.0", 1, 2)
    assert info.hard_limits == DriveLimits(AxisLimits(0, 75308), AxisLimits(0, 68745))
    assert drive.get_limits() == LIMITS
    narrow = DriveLimits(AxisLimits(500, 70000), AxisLimits(500, 60000))
    drive.set_limits(narrow)
    assert drive.get_limits() == narrow
    assert (controllers[1].el.soft_min, controllers[1].el.soft_max) == (500, 60000)
    with pytest.raises(ModbusLimitError, match="exception 3"):
        drive.set_limits(DriveLimits(AxisLimits(0, 80000), AxisLimits(500, 60000)))
    # limits that would leave the axis (at stow, 500) outside its soft range are refused too
    with pytest.raises(ModbusLimitError, match="exception 3"):
        drive.set_limits(DriveLimits(AxisLimits(1000, 70000), AxisLimits(500, 60000)))
    assert drive.get_limits() == narrow


def test_move_and_wait_and_jog(drive, controllers, sim):
    st = drive.move_and_wait(4000, 3000, timeout_s=scaled_s(5))
    assert (st.az_steps, st.el_steps) == (4000, 3000)
    drive.jog(-250, 125)
    assert drive.last_targets == (3750, 3125)
    st = drive.wait_in_position(scaled_s(5))
    assert (st.az_steps, st.el_steps) == (3750, 3125)
    assert [e.command for e in controllers[1].log] == ["MOVE_ABS", "JOG"]
    assert controllers[1].log[1].args == (-250, 125)


@pytest.mark.parametrize(("az", "el"), [(499, 1000), (1000, 68201), (-1, 1000), (2 ** 40, 1000)])
def test_out_of_range_move_never_reaches_the_device(drive, sim, controllers, az, el):
    with pytest.raises(LimitError, match="outside the soft limits.*nothing was sent"):
        drive.move_abs(az, el)
    assert sim.writes == [] and controllers[1].log == []


def test_out_of_range_jog_never_reaches_the_device(drive, sim, controllers):
    with pytest.raises(LimitError, match="jog result az_steps=499"):
        drive.jog(-1, 0)
    assert sim.writes == [] and controllers[1].log == []


def test_device_limits_narrower_than_config(drive, sim, controllers):
    """The configuration allows 600 but the device was set to [1000, ...]: the device
    refuses the setpoint with exception 3; nothing moves."""
    controllers[1].restore_limits(1000, 74800, 500, 68200)  # as set on site, before this session
    with pytest.raises(ModbusLimitError) as exc:
        drive.move_abs(600, 600)
    err = exc.value
    assert isinstance(err, LimitError) and isinstance(err, NakError)
    assert (err.unit, err.function_code, err.address, err.exception_code) == (1, 16, 0, 3)
    assert "unit 1" in str(err) and "az_target_steps..el_target_steps" in str(err)
    assert "Modbus exception 3 (illegal data value)" in str(err)
    assert controllers[1].log == []  # nothing executed
    assert drive.status().az_target == 500


def test_fault_refusal_names_the_reason(drive, controllers):
    controllers[1].inject_stall("az")
    with pytest.raises(ModbusExceptionError) as exc:
        drive.move_abs(2000, 2000)
    assert exc.value.exception_code == 4 and exc.value.code == Reject.FAULT_ACTIVE
    assert "write holding register 8 (command)" in str(exc.value)
    assert "MOVE rejected by the firmware: FAULT_ACTIVE" in str(exc.value)
    with pytest.raises(ActuatorFault, match="stall_az"):
        drive.wait_in_position(scaled_s(1))
    drive.clear_fault()
    assert drive.status().faults == ()


def test_silent_unit_times_out_with_retries(link):
    silent = ModbusDrive(link, 9, LIMITS)
    t0 = time.monotonic()
    with pytest.raises(LinkError, match=r"unit 9: no answer to read input register 0-11 .* "
                                        rf"after 2 attempt\(s\), timeout {link.timeout_s:g} s: no response"):
        silent.status()
    assert time.monotonic() - t0 >= 2 * link.timeout_s  # two attempts of the timeout each
    assert silent.retries_used == 0 and link.retries_used == 1


def test_nobody_listening(controllers):
    with socket.socket() as s:            # a port that was free a moment ago
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    drive = ModbusDrive(ModbusLink.tcp("127.0.0.1", port, timeout_s=scaled_s(0.1), retries=0), 1, LIMITS)
    with pytest.raises(LinkError, match=f"modbus-tcp 127.0.0.1:{port} unit 1: no answer"):
        drive.status()


def test_server_stops_mid_move_then_comes_back(drive, sim):
    drive.move_abs(9000, 8000)
    assert drive.status().moving
    sim.pause("tcp")
    with pytest.raises(LinkError):
        drive.status()
    time.sleep(0.1)
    sim.resume("tcp")
    st = drive.status()                          # the same drive reconnects by itself
    assert (st.az_target, st.el_target) == (9000, 8000)
    st = drive.wait_in_position(scaled_s(10))
    assert (st.az_steps, st.el_steps) == (9000, 8000)


def test_read_back_mismatch_stops_before_the_command(drive, sim, controllers, monkeypatch):
    real_read = drive.link.read

    def corrupt(unit, table, address, count, **kw):
        words, n = real_read(unit, table, address, count, **kw)
        if table == "holding":
            words[1] ^= 1
        return words, n

    monkeypatch.setattr(drive.link, "read", corrupt)
    with pytest.raises(DriveError, match="read-back mismatch.*no command was sent"):
        drive.move_abs(2000, 2000)
    assert not any("command" in w.decoded for w in sim.writes)
    assert controllers[1].log == []


def test_lost_answer_to_jog_is_not_resent(drive, controllers, monkeypatch):
    """The JOG executes but its answer is lost: re-sending would jog twice."""
    real_write = drive.link.write
    lost = []

    def lose_first_command_answer(unit, address, words, **kw):
        n = real_write(unit, address, words, **kw)
        if address == 8 and not lost:
            lost.append(words)
            raise LinkError("answer lost (test)")
        return n

    monkeypatch.setattr(drive.link, "write", lose_first_command_answer)
    drive.jog(300, 0)
    assert lost and [e.command for e in controllers[1].log] == ["JOG"]
    assert drive.status().az_target == 800 and drive.retries_used == 1


def test_lost_request_is_resent(drive, controllers, monkeypatch):
    real_write = drive.link.write
    dropped = []

    def drop_first_command(unit, address, words, **kw):
        if address == 8 and not dropped:
            dropped.append(words)
            raise LinkError("request lost (test)")
        return real_write(unit, address, words, **kw)

    monkeypatch.setattr(drive.link, "write", drop_first_command)
    drive.stop()
    assert [e.command for e in controllers[1].log] == ["STOP"]


def test_home_and_stow(drive, controllers):
    drive.move_and_wait(3000, 3000, timeout_s=scaled_s(5))
    drive.home()
    assert drive.wait_in_position(scaled_s(5)).az_steps == 500
    drive.stow()
    assert [e.command for e in controllers[1].log][-2:] == ["HOME", "STOW"]


def test_units_polled_from_threads_share_one_link(link):
    drives = [ModbusDrive(link, u, LIMITS) for u in (1, 2)]
    errors, results = [], {1: set(), 2: set()}

    def poll(d):
        try:
            for _ in range(50):
                st = d.status()
                results[d.unit].add((st.unit, st.az_steps, st.el_steps))
        except Exception as exc:  # noqa: BLE001 - collected for the assert
            errors.append(exc)

    threads = [threading.Thread(target=poll, args=(d,)) for d in drives]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    assert results == {1: {(1, 500, 500)}, 2: {(2, 1000, 2000)}}


def test_rtu_over_a_pty(sim, controllers, tmp_path):
    device = sim.start_rtu(str(tmp_path / "rs485"))
    link = ModbusLink.rtu(device, timeout_s=scaled_s(0.3), retries=1)
    try:
        d2 = ModbusDrive(link, 2, LIMITS)
        assert d2.status().az_steps == 1000
        st = d2.move_and_wait(1500, 1800, timeout_s=scaled_s(5))
        assert (st.az_steps, st.el_steps) == (1500, 1800)
        with pytest.raises(LinkError, match="modbus-rtu .* unit 7: no answer"):
            ModbusDrive(link, 7, LIMITS).status()
        assert ModbusDrive(link, 1, LIMITS).status().az_steps == 500
    finally:
        link.close()


def test_link_pool_builds_modbus_drives(sim, tmp_path):
    device = sim.start_rtu(str(tmp_path / "bus"))
    with LinkPool(timeout_s=scaled_s(0.3), retries=0) as pool:
        a = pool.drive(ModbusTcpLink(kind="modbus-tcp", host="127.0.0.1", port=sim.port, unit=1), LIMITS)
        b = pool.drive(ModbusTcpLink(kind="modbus-tcp", host="127.0.0.1", port=sim.port, unit=2), LIMITS)
        c = pool.drive(ModbusRtuLink(kind="modbus-rtu", device=device, unit=2), LIMITS)
        assert a.link is b.link and c.link is not a.link
        assert (a.status().az_steps, b.status().az_steps, c.status().el_steps) == (500, 1000, 2000)


def test_dropped_connection_is_reestablished_transparently(drive, sim, link):
    assert drive.status().az_steps == 500
    sim.pause("tcp")          # the server drops every open connection ...
    sim.resume("tcp")         # ... and listens again at once
    before = link.retries_used
    assert drive.status().az_steps == 500      # one retry on a fresh connection
    assert link.retries_used - before <= 1
