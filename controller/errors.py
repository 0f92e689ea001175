"""Exceptions shared by every layer, and how the CLI maps them to exit codes.

``HeliocalError`` and its subclasses carry a message that already names the file, key or
byte at fault. The CLI prints it on one line and exits with ``exit_code`` (2 for bad input),
never with a traceback.
"""

from __future__ import annotations


class HeliocalError(Exception):
    """Base class of all errors the CLI reports cleanly. Exit status 1 unless overridden.

    ``outcome`` says, for a command to a device, whether the device executed it:
    ``"executed"``, ``"not_executed"`` or ``"unknown"`` (no answer after it was sent — a
    script must check the device's state before sending it again); None where it does not
    apply."""

    exit_code = 1
    outcome: str | None = None


class InputError(HeliocalError):
    """Bad input from the user: a file, a key, a value or an option. Exit status 2."""

    exit_code = 2


class ConfigError(InputError):
    """The plant configuration is unreadable or invalid. The message names file and key."""


class LimitError(InputError):
    """A requested position is outside an axis' soft limits. Nothing was sent."""

    outcome = "not_executed"


class DeviceError(HeliocalError):
    """A device (drive, camera) failed or answered with an error. Exit status 1."""


class NoBeamError(HeliocalError):
    """The image holds no beam by the presence decision (controller.imaging.presence): not bad
    input, not a device failure. Exit status 4. ``detail`` is the decision's JSON
    (``beam``: false, ``statistic``, ``statistic_name``, ``threshold``)."""

    exit_code = 4

    def __init__(self, message: str, detail: dict | None = None) -> None:
        super().__init__(message)
        self.detail = detail or {}
