"""Soft limits are checked in the controller before anything reaches a link."""

import pytest

from controller.devices.drive import (
    AxisLimits,
    Drive,
    DriveError,
    DriveLimits,
    DriveStatus,
    FirmwareInfo,
    LinkError,
)
from controller.devices.plant_time import PlantTime
from controller.errors import LimitError


class RecordingDrive(Drive):
    """A drive whose link is a list: it records what would have been sent."""

    def __init__(self) -> None:
        self.unit = 3
        self.limits = DriveLimits(AxisLimits(0, 1000), AxisLimits(-50, 50))
        self.sent: list[tuple] = []

    def status(self) -> DriveStatus:
        return DriveStatus(3, 10, 0, 990, 0, False, True)

    def _send_move_abs(self, az, el):
        self.sent.append(("move", az, el))

    def _send_jog(self, daz, delv):
        self.sent.append(("jog", daz, delv))

    def info(self):
        return FirmwareInfo(1, 2, self.limits, "recording")

    def get_limits(self) -> DriveLimits:
        return self.limits

    def set_limits(self, limits: DriveLimits) -> None:
        self.sent.append(("limits", limits))

    stop = home = stow = clear_fault = close = lambda self: None


@pytest.mark.parametrize("az, el", [(1001, 0), (-1, 0), (0, 51), (0, -51), (0.5, 0), (True, 0)])
def test_out_of_range_move_never_sent(az, el):
    d = RecordingDrive()
    with pytest.raises(LimitError):
        d.move_abs(az, el)
    assert d.sent == []


def test_jog_checked_against_resulting_target():
    d = RecordingDrive()
    with pytest.raises(LimitError, match="az_steps=1001"):
        d.jog(11, 0)  # the target is 990, so +11 would end at 1001
    d.jog(10, -50)
    assert d.sent == [("jog", 10, -50)]


class FlakyDrive(RecordingDrive):
    """Answers status from a script: a LinkError where the script says None."""

    def __init__(self, script) -> None:
        super().__init__()
        self.script = list(script)

    def status(self) -> DriveStatus:
        st = self.script.pop(0)
        if st is None:
            raise LinkError("unit 3: no valid reply to GET_STATUS")
        return st


def _at(az, moving):
    return DriveStatus(3, az, 0, 990, 0, moving, not moving)


def test_wait_tolerates_single_missed_polls():
    d = FlakyDrive([_at(10, True), None, _at(500, True), None, None, _at(990, False)])
    st = d.wait_in_position(10.0, PlantTime(sleep=lambda s: None, poll_s=0.0), expect=(990, 0))
    assert st.az_steps == 990 and d.script == []


def test_wait_gives_up_after_three_missed_polls_with_outcome_unknown():
    d = FlakyDrive([_at(10, True), None, None, None, _at(990, False)])
    with pytest.raises(LinkError, match="3 status polls in a row unanswered") as exc:
        d.wait_in_position(10.0, PlantTime(sleep=lambda s: None, poll_s=0.0))
    assert exc.value.outcome == "unknown"


def test_wait_deadline_uses_the_given_clock():
    """One clock for the deadline and the polling: 5 plant seconds pass in 5 polls of 1 s."""
    t = [0.0]
    d = FlakyDrive([_at(10, True)] * 10)
    with pytest.raises(DriveError, match="not in position after 5 s"):
        d.wait_in_position(5.0, PlantTime(now=lambda: t[0], sleep=lambda s: t.__setitem__(0, t[0] + s),
                                          poll_s=1.0))
    assert len(d.script) == 10 - 6


@pytest.mark.parametrize("args, fragment", [
    (["--timeout", "nan", "status"], "argument --timeout: nan is not a finite number (range (0, 60])"),
    (["--timeout", "inf", "status"], "argument --timeout: inf is not a finite number (range (0, 60])"),
    (["--retries", "100000000", "status"], "argument --retries: 100000000 is outside [0, 100]"),
    (["move", "--az-steps", "1", "--el-steps", "1", "--wait", "--wait-timeout", "nan"], "--wait-timeout"),
])
def test_drive_rejects_non_finite_and_huge_options(capsys, args, fragment):
    from controller.cli import main

    assert main(["drive", "--serial", "/dev/null-no-such", "--unit", "1", *args]) == 2
    assert fragment in capsys.readouterr().err
