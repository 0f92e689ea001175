"""Alarms as ISA-18.2 describes them: states, one alarm per condition and source, a history
never rewritten, acknowledge and shelve with who and until when; what a campaign's runs and a
night's end raise and clear (controller.alarms, controller.storage.alarms)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from controller.alarm_config import AlarmLimits
from controller.alarms.conditions import CONDITIONS
from controller.alarms.states import parse_duration
from controller.alarms.watch import FieldWatch, night_alarms
from controller.calibration.records import MeasurementRecord, ModelRecord, RunRecord
from controller.errors import InputError
from controller.storage.alarms import AlarmBook
from controller.storage.audit import audit_entries
from controller.storage.db import CampaignStore


class Clock:
    def __init__(self) -> None:
        self.now = datetime(2026, 6, 21, 22, 0, tzinfo=UTC)

    def __call__(self) -> datetime:
        return self.now


@pytest.fixture
def book(tmp_path):
    with CampaignStore(tmp_path / "a.db") as store:
        yield AlarmBook(store, Clock())


def _states(book):
    return {(a.condition, a.source): a.state(book.clock()) for a in book.alarms(include_normal=True)}


def test_an_alarm_goes_through_the_isa_states_and_its_history_keeps_every_step(book):
    book.raise_alarm("lamp_not_dark", "lamp", "lamp lamp did not confirm dark")
    book.raise_alarm("lamp_not_dark", "lamp", "again")  # still active: no second alarm, no event
    (a,) = book.alarms()
    assert (a.state(book.clock()), a.count, a.priority, a.severity) == ("unack_active", 1, "high", 800)
    book.clock.now += timedelta(minutes=5)
    book.clear_alarm("lamp_not_dark")
    assert _states(book) == {("lamp_not_dark", "lamp"): "unack_rtn"}  # back to normal, still to acknowledge
    book.raise_alarm("lamp_not_dark", "lamp", "it chatters")  # the same alarm again: counted
    assert book.alarm(a.id).count == 2 and _states(book)[("lamp_not_dark", "lamp")] == "unack_active"
    acked = book.acknowledge(a.id, "alice", "switched off at the breaker")
    assert (acked.acked_by, acked.ack_comment, acked.state(book.clock())) == \
        ("alice", "switched off at the breaker", "ack_active")
    with pytest.raises(InputError, match="already acknowledged by alice"):
        book.acknowledge(a.id, "bob")
    book.clear_alarm("lamp_not_dark", "lamp")
    assert book.alarms() == [] and _states(book) == {("lamp_not_dark", "lamp"): "normal"}
    kinds = [(e["kind"], e["user"]) for e in book.events()]
    assert kinds == [("raised", None), ("cleared", None), ("raised", None), ("acknowledged", "alice"),
                     ("cleared", None)]
    (entry,) = audit_entries(book.store)
    assert (entry["user"], entry["action"], entry["target"]) == \
        ("alice", "alarm.acknowledge", f"alarm {a.id}")


def test_a_shelved_alarm_is_hidden_until_its_expiry(book):
    book.raise_alarm("no_beam_repeated", "tower-target", "3 in a row")
    (a,) = book.alarms()
    book.shelve(a.id, "bob", parse_duration("1h30m"))
    assert book.alarm(a.id).state(book.clock()) == "shelved" and book.alarm(a.id).shelved_by == "bob"
    book.clock.now += timedelta(minutes=89)
    assert book.alarm(a.id).state(book.clock()) == "shelved"
    book.clock.now += timedelta(minutes=2)
    assert book.alarm(a.id).state(book.clock()) == "unack_active"  # the shelve expired
    with pytest.raises(InputError, match="at most 7 days"):
        book.shelve(a.id, "bob", timedelta(days=8))
    with pytest.raises(InputError, match="no alarm 99"):
        book.acknowledge(99, "bob")


@pytest.mark.parametrize("text,seconds", [("30m", 1800), ("2h", 7200), ("1h30m", 5400), ("90s", 90),
                                          ("1d", 86400), ("0.5h", 1800)])
def test_durations(text, seconds):
    assert parse_duration(text).total_seconds() == seconds


@pytest.mark.parametrize("text", ["", "2", "2 hours", "h", "-1h", "1h and 3m"])
def test_bad_durations_are_refused_naming_them(text):
    with pytest.raises(InputError, match="not a duration"):
        parse_duration(text)


def _run(hid, status, cause=None, measured=False, error=None, model=False) -> RunRecord:
    m = [MeasurementRecord(1, 0, 0, (0, 0, 1), 0, 90, (0, 0, 30), 0.0)] if measured else []
    return RunRecord(hid, 0, status, "done", 1, 0.0, 1.0, error_before_mrad=error, fault_cause=cause,
                     measurements=m, model=ModelRecord({}, {}, 0.1, 3) if model else None)


class Audit:
    def __init__(self) -> None:
        self.rows = []

    def record(self, action, target="", detail=""):
        self.rows.append((action, target))


def test_a_campaigns_runs_raise_and_clear_their_alarms(book):
    audit = Audit()
    w = FieldWatch(book, audit, AlarmLimits(drift_limit_mrad=4.0), "tower-target", "c1",
                   lambda ids: {"H01", "H03"} & set(ids))
    w.campaign_started(1, ["H01", "H02", "H03"], set())
    w.run_recorded(1, _run("H01", "failed", "LinkError: H01: no answer after 3 tries"))
    w.run_recorded(1, _run("H02", "failed", "UnsafePath: the slew would cross tower-lower"))
    w.run_recorded(1, _run("H03", "failed", "CameraError: no frame from ccd1"))
    for hid in ("H04", "H05", "H06"):
        w.run_recorded(1, _run(hid, "no_beam", "NoBeam: statistic 0.2 below 5"))
    w.run_recorded(1, _run("H03", "calibrated", measured=True, error=6.0, model=True))  # drifted, had a model
    w.run_recorded(1, _run("H02", "calibrated", measured=True, error=9.0))  # no model before: not drift
    active = {(a.condition, a.source) for a in book.alarms() if a.active}
    assert active == {("drive_link_down", "H01"), ("drift_high", "H03")}  # the rest cleared by a beam seen
    history = {(e["kind"], book.alarm(e["alarm_id"]).condition) for e in book.events()}
    assert {("raised", c) for c in ("beam_safety_refusal", "camera_gone", "no_beam_repeated")} <= history
    assert {("cleared", c) for c in ("beam_safety_refusal", "camera_gone", "no_beam_repeated")} <= history
    assert audit.rows == [("model.update", "H03")]
    w.run_recorded(1, _run("H01", "calibrated", measured=True, error=1.0, model=True))
    assert ("drive_link_down", "H01") not in {(a.condition, a.source) for a in book.alarms() if a.active}


def test_a_nights_end_raises_partial_and_each_heliostats_predicted_error(book):
    limits = AlarmLimits(daytime_error_limit_mrad=2.0)
    night_alarms(book, limits, "f/night-1", "partial", "f/night-1/lamp: 2 failed", {"H01": 2.5, "H02": 1.0},
                 ["H01", "H02"])
    assert {(a.condition, a.source) for a in book.alarms()} == {("night_partial", "night"),
                                                                 ("daytime_error_high", "H01")}
    night_alarms(book, limits, "f/night-2", "finished", None, {"H01": 1.5}, ["H01", "H02"])
    assert not [a for a in book.alarms() if a.active]


def test_every_condition_of_the_issue_is_in_the_catalogue():
    assert set(CONDITIONS) == {"lamp_not_dark", "lamp_not_lit", "drive_link_down", "camera_gone",
                               "no_beam_repeated", "beam_safety_refusal", "daytime_error_high", "drift_high",
                               "night_partial"}
