"""Soft limits are checked in the controller before anything reaches a link."""

import pytest

from controller.devices.drive import AxisLimits, Drive, DriveLimits, DriveStatus, FirmwareInfo
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
