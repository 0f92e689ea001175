"""Actuator physics of the simulated firmware, driven by an injected clock (no sleeping)."""

import pytest

from firmware_proto.faults import Fault, Reject, fault_names
from simplant.firmware.physics import AxisParams, SimController


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def make(backlash: int = 0, speed: float = 100.0, accel: float = 200.0) -> tuple[SimController, FakeClock]:
    clock = FakeClock()
    axis = AxisParams(soft_min=100, soft_max=900, hard_min=0, hard_max=1000,
                      speed=speed, acceleration=accel, backlash=backlash)
    ctl = SimController(1, axis, AxisParams(100, 900, 0, 1000, speed=speed, acceleration=accel),
                        clock=clock, initial_steps=(500, 500))
    return ctl, clock


def test_trapezoidal_move_takes_the_expected_time():
    # 200 steps at v=100 steps/s, a=200 steps/s^2: ramps of 0.5 s (25 steps each) and
    # 150 steps at full speed (1.5 s): 2.5 s in all.
    ctl, clock = make()
    assert ctl.move_abs(700, 500) == Reject.OK
    clock.t = 2.4
    st = ctl.status()
    assert st["moving"] and 690 <= st["az_steps"] < 700
    clock.t = 2.6
    st = ctl.status()
    assert not st["moving"] and st["in_position"] and st["az_steps"] == 700


def test_soft_limits_refuse_and_leave_target_unchanged():
    ctl, clock = make()
    assert ctl.move_abs(901, 500) == Reject.OUT_OF_RANGE
    assert ctl.move_abs(500, 99) == Reject.OUT_OF_RANGE
    assert ctl.jog(401, 0) == Reject.OUT_OF_RANGE
    assert ctl.status()["az_target"] == 500
    assert [e.result for e in ctl.log] == [Reject.OUT_OF_RANGE] * 3


def test_backlash_lags_output_after_reversal():
    ctl, clock = make(backlash=7)
    ctl.move_abs(600, 500)
    clock.t = 10
    ctl.move_abs(550, 500)
    clock.t = 20
    assert ctl.status()["az_steps"] == 550
    out_az, _ = ctl.output_steps()
    assert out_az == pytest.approx(557.0)  # the rod stops short by the backlash


def test_reversal_inside_the_backlash_gap_does_not_ratchet():
    # Up 100, back 5 (inside the 7-step gap: the rod stays), up 100 again: the motor has only
    # crossed back the 5 steps, so the rod follows after 5 steps and ends where a plain up
    # move would leave it. Resetting the slack to the whole gap at every reversal left the rod
    # 7 steps behind the motor after each such wiggle, drifting further each time.
    ctl, clock = make(backlash=7)
    for k, target in enumerate((600, 595, 695, 690, 790)):
        ctl.move_abs(target, 500)
        clock.t = 10.0 * (k + 1)
    assert ctl.status()["az_steps"] == 790
    out_az, _ = ctl.output_steps()
    assert out_az == pytest.approx(790.0)


def test_stall_latches_until_clear_and_blocks_motion():
    ctl, clock = make()
    ctl.move_abs(800, 500)
    clock.t = 1.0
    ctl.inject_stall("az")
    pos = ctl.status()["az_steps"]
    clock.t = 5.0
    st = ctl.status()
    assert st["az_steps"] == pos and not st["in_position"]
    assert fault_names(st["faults"]) == ["stall_az"]
    assert ctl.move_abs(600, 500) == Reject.FAULT_ACTIVE
    assert ctl.clear_fault() == Reject.OK
    assert ctl.move_abs(600, 500) == Reject.OK


def test_power_cycle_stops_and_latches():
    ctl, clock = make()
    ctl.move_abs(800, 500)
    clock.t = 1.0
    ctl.power_cycle()
    st = ctl.status()
    assert st["faults"] == Fault.POWER_CYCLE and not st["moving"]
    assert st["az_target"] == st["az_steps"] < 800


def test_hard_limit_latch_when_soft_limits_widened_past_it():
    ctl, clock = make(speed=1000, accel=10000)
    assert ctl.set_limits(0, 1001, 0, 1000) == Reject.BAD_LIMITS
    assert ctl.set_limits(0, 1000, 0, 1000) == Reject.OK
    ctl.inject_limit_hit("el")
    assert "limit_el" in fault_names(ctl.status()["faults"])
    assert ctl.status()["limit_el"]
