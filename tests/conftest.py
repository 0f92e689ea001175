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

import pytest

TIME_FACTOR = float(os.environ.get("HELIOCAL_TEST_TIME_FACTOR", "1") or "1")


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
