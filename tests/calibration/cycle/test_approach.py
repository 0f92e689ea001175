"""Anti-backlash approach: measuring moves end with both axes moving up past the backlash."""

from __future__ import annotations

from controller.calibration.cycle.approach import MARGIN_STEPS, approach_path
from controller.devices.drive import AxisLimits, DriveLimits

LIM = DriveLimits(AxisLimits(500, 74800), AxisLimits(500, 68200))


def test_from_above_goes_below_first_then_up():
    path = approach_path((30000, 20000), (25000, 15000), (12, 12), LIM)
    assert path == [(25000 - 12 - MARGIN_STEPS, 15000 - 12 - MARGIN_STEPS), (25000, 15000)]


def test_from_far_below_goes_straight():
    assert approach_path((20000, 10000), (25000, 15000), (12, 12), LIM) == [(25000, 15000)]


def test_only_the_axis_that_needs_it_is_pre_positioned():
    path = approach_path((20000, 16000), (25000, 15000), (12, 12), LIM)
    assert path == [(25000, 15000 - 12 - MARGIN_STEPS), (25000, 15000)]


def test_unknown_start_close_below_and_no_backlash():
    assert approach_path(None, (25000, 15000), (12, 0), LIM) == [(25000 - 12 - MARGIN_STEPS, 15000),
                                                                  (25000, 15000)]
    assert approach_path((24995, 14995), (25000, 15000), (12, 12), LIM)[0][0] < 24995
    assert approach_path((30000, 20000), (25000, 15000), (0, 0), LIM) == [(25000, 15000)]


def test_pre_position_respects_the_soft_limits():
    path = approach_path((600, 600), (505, 510), (12, 12), LIM)
    assert path[0] == (500, 500) and path[-1] == (505, 510)


def test_the_move_down_from_just_below_is_longer_than_the_backlash():
    """Starting a few steps below the target (an axis the slew from standby hardly moves), the
    pre-position is the margin below the *present* steps, not the target: a reversal shorter
    than the play would leave the gear between its flanks."""
    path = approach_path((24990, 20000), (25000, 15000), (12, 12), LIM)
    assert path == [(24990 - 12 - MARGIN_STEPS, 15000 - 12 - MARGIN_STEPS), (25000, 15000)]
    assert 24990 - path[0][0] > 12 and 20000 - path[0][1] > 12
