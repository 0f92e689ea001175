"""Suite-wide settings.

Every timing constant of the tests (deadlines, poll periods, timeouts handed to the code
under test) is multiplied by one factor, ``HELIOCAL_TEST_TIME_FACTOR`` (default 1), so a
slow or loaded machine can stretch them all at once: ``HELIOCAL_TEST_TIME_FACTOR=3 make test``.
Use the ``scaled`` fixture (or :func:`scaled_s`) for such constants.
"""

from __future__ import annotations

import contextlib
import io
import os
import signal

import pytest

TIME_FACTOR = float(os.environ.get("HELIOCAL_TEST_TIME_FACTOR", "1") or "1")

# The Ctrl-C tests interrupt this process and send SIGINT to the commands they start. A suite
# started in the background by a shell without job control (`make test &` in a script) inherits
# SIGINT ignored, and so would those commands (an ignored signal stays ignored across exec):
# the tests would then test the shell's choice, not heliocal. Python's own handler here makes
# every child start with the default disposition, as from a terminal.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


def scaled_s(seconds: float) -> float:
    """``seconds`` times the suite's time factor."""
    return seconds * TIME_FACTOR


@pytest.fixture
def scaled():
    """The time-scaling function: ``scaled(0.5)`` -> 0.5 s times HELIOCAL_TEST_TIME_FACTOR."""
    return scaled_s


def run_cli(argv: list[str]) -> tuple[int, str, str]:
    """``heliocal argv`` in this process: (exit code, stdout, stderr)."""
    from controller.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code
    return code, out.getvalue(), err.getvalue()
