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


def aravis_missing() -> str | None:
    """Why Aravis 0.8 cannot be loaded here (what to install), None when it can."""
    from controller.errors import DeviceError
    from simplant.devices.gige_imager import aravis

    try:
        aravis()
    except DeviceError as exc:
        return str(exc)
    return None


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


# The slowest tests (`pytest --durations`, 2-core machine, 2026-11-30), in that order, are collected
# first: xdist deals them out first, to both workers at once, instead of one worker finishing a
# minute-long test alone while the other has run out of work.
SLOW_FIRST = (
    "tests/test_docs_commands.py::test_every_shown_command_runs[results.md]",
    "tests/calibration/night/test_night_cli.py::test_planned_nights_in_separate_processes_resume_and_improve_the_day",
    "tests/calibration/campaign/test_campaign_sim.py::"
    "test_demo_uncalibrated_field_compares_the_coarse_correction_with_centroid_only",
    *(f"tests/test_rehearsal.py::{name}" for name in (
        "test_the_plant_writes_the_demo_field_with_the_devices_addresses",
        "test_campaign_run_measures_the_heliostats_on_real_transports",
        "test_campaign_night_measures_the_heliostats_on_real_transports",
        "test_every_lamp_reads_dark_after_each_normal_end", "test_the_product_and_mbpoll_read_the_same_lamps",
        "test_sigint_stops_the_plant_and_removes_what_it_created")),
    "tests/test_docs_commands.py::test_every_shown_command_runs[getting-started.md]",
    "tests/calibration/night/test_nights_resume.py::test_kill_9_mid_planned_night_then_resume",
    "tests/calibration/campaign/test_campaign_sim.py::test_planned_night_measures_other_geometries_and_explains_them",
    "tests/test_new_user.py::test_readme_session_outside_the_repository",
)


def pytest_collection_modifyitems(config, items):
    first = {nodeid: i for i, nodeid in enumerate(SLOW_FIRST)}
    # stable: the rest keep their order; a grouped test's id may end in "@group" (xdist)
    items.sort(key=lambda item: first.get(item.nodeid.split("@")[0], len(first)))
