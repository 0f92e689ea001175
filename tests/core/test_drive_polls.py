"""A moving drive is polled less often far from its move's end, and its end is still caught
within one polling period (``controller.devices.drive.poll_pause``)."""

import contextlib

import pytest

from controller.devices.drive import POLL_PAUSE_MAX, AxisLimits, DriveLimits, DriveStatus, poll_pause
from controller.devices.plant_time import PlantTime
from simplant.devices.inproc import InProcDrive
from simplant.firmware.physics import AxisParams, SimController

POLL_S = 0.1
# The configured axes (configs/demo.yaml): 1,540 steps/s, 3,000 steps/s².
AXIS = AxisParams(0, 80000, 0, 80000, speed=1540.0, acceleration=3000.0, backlash=12)


def _drive(t: list[float]) -> InProcDrive:
    ctl = SimController(1, AXIS, AXIS, clock=lambda: t[0], initial_steps=(1000, 1000))
    return InProcDrive(ctl, DriveLimits(AxisLimits(0, 80000), AxisLimits(0, 80000)))


def _true_end(target: tuple[int, int]) -> float:
    """When the move to ``target`` ends, on a second firmware stepped by 1 ms."""
    own = [0.0]
    ctl = _drive(own).ctl
    ctl.move_abs(*target)
    while not ctl.status()["in_position"]:
        own[0] += 1e-3
    return own[0]


def _wait(distance: tuple[int, int], watch=None, computing=contextlib.nullcontext,
          on_read=lambda: None) -> tuple[int, float, float]:
    """Polls, the time the wait returned and the move's true end, for a move by ``distance``
    (``computing``: the plant time's; ``on_read``: called at each status read)."""
    t = [0.0]
    drive = _drive(t)
    target = (1000 + distance[0], 1000 + distance[1])
    end = _true_end(target)
    polls = [0]
    status = drive.status

    def counted() -> DriveStatus:
        polls[0] += 1
        on_read()
        return status()
    drive.status = counted
    time = PlantTime(now=lambda: t[0], sleep=lambda s: t.__setitem__(0, t[0] + s), poll_s=POLL_S,
                     computing=computing)
    st = drive.move_and_wait(*target, timeout_s=120.0, time=time, watch=watch)
    assert (st.az_steps, st.el_steps) == target
    return polls[0], t[0], end


@pytest.mark.parametrize("distance", [(12, 0), (50, 50), (200, 0), (400, 30), (800, 800), (1500, 40),
                                      (3000, 3000), (6000, 100), (12000, 9000), (30000, 2000)])
def test_the_end_of_a_move_is_caught_within_one_polling_period(distance):
    polls, returned, end = _wait(distance)
    assert end - 1e-3 <= returned <= end + POLL_S + 1e-9  # the true end to the 1 ms it was stepped by
    assert polls <= (end / POLL_S) + 3  # never more than polling every period


def test_a_long_move_is_read_a_few_times_not_every_period():
    polls, returned, end = _wait((30000, 2000))
    assert end > 19.0  # a 20 s move: 200 periods
    assert polls <= 40


def test_a_watch_asking_to_be_kept_posted_gets_every_period():
    seen = []

    def watch(st: DriveStatus) -> bool:
        seen.append(st.az_steps)
        return True
    polls, _, end = _wait((6000, 0), watch)
    assert polls >= end / POLL_S - 1 and len(seen) == polls


def test_each_status_is_judged_inside_the_controllers_computing_and_read_outside_it():
    """A simulated plant's clock runs at 1x while the controller computes (``PlantTime.computing``):
    the judgement of every status read (faults, the watch's ray trace, the next pause) is the
    controller's work; the read waits for the plant's answer and is not."""
    inside, where = [0], []

    @contextlib.contextmanager
    def computing():
        inside[0] += 1
        try:
            yield
        finally:
            inside[0] -= 1

    def watch(st: DriveStatus) -> bool:
        where.append(("watch", inside[0]))
        return False
    polls, _, _ = _wait((3000, 0), watch, computing, lambda: where.append(("read", inside[0])))
    assert polls > 3 and len(where) == 2 * polls
    assert all(depth == (kind == "watch") for kind, depth in where)


def test_the_pause_is_polling_period_until_the_drive_is_seen_moving_and_capped():
    still = DriveStatus(1, 1000, 1000, 9000, 1000, True, False)
    assert poll_pause(POLL_S, still, still, 0.1) == POLL_S  # commanded, not yet moving (or stalled)
    far = DriveStatus(1, 1001, 1000, 90000, 1000, True, False)
    assert poll_pause(POLL_S, still, far, 0.1) == POLL_PAUSE_MAX * POLL_S
    near = DriveStatus(1, 8990, 1000, 9000, 1000, True, False)
    assert poll_pause(POLL_S, DriveStatus(1, 8000, 1000, 9000, 1000, True, False), near, 0.5) == POLL_S
