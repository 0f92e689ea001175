"""Lights out at every end (issue 40, docs/lamps.md "Lights out"): a calibration campaign (what
``campaign run`` runs), a planned night (``campaign night``, the console's night, the demo) that
ends finished or partial, stopped by an exception, or with a lamp that stays lit. Checked on the
simulated plant's lamp panel over Modbus TCP, read by mbpoll (libmodbus) and by ``heliocal lamps
status --json`` from outside the product's own connection, and in the store's ``lamp_states``."""

from __future__ import annotations

import json
import shutil
import subprocess

import pytest
import yaml

from controller.calibration.campaign.lights_out import LampNotDark
from controller.calibration.campaign.observers import CampaignObserver
from controller.calibration.campaign.runner import Campaign, CampaignOptions
from controller.calibration.night.planned import PlannedNight, calibration_night
from controller.commands.field import open_store
from controller.commands.simulated import simulated_field
from controller.config import load_config
from controller.storage.lamp_states import lamp_states, lamps_not_dark
from controller.storage.nights import NightBook
from simplant.settings import SimulationSettings
from tests.calibration.conftest import FAST
from tests.conftest import run_cli, scaled_s

IDS = ["H02"]


@pytest.fixture
def field(small_config, tmp_path):
    """The simulated field (its lamp panel on 127.0.0.1) and its configuration as a file, so
    other programs reach the same panel."""
    store = open_store(tmp_path / "c.db")
    settings = SimulationSettings(clock_speedup=FAST.clock_speedup, seed=5)
    with simulated_field(load_config(small_config), str(small_config), store, tmp_path / "sim", IDS, settings,
                         night=0, library=None) as fs:
        fs.field.lamps.timeout_s = scaled_s(2.0)
        path = tmp_path / "plant.yaml"
        path.write_text(yaml.safe_dump(fs.plant.data, sort_keys=False))
        yield fs, path
    store.close()


class _Told(CampaignObserver):
    def __init__(self) -> None:
        self.not_dark: list[tuple[str, str, str]] = []

    def lamp_not_dark(self, session, lamp) -> None:
        self.not_dark.append((session, lamp.channel, lamp.state))


def _outside_view(path) -> tuple[dict[str, bool], list[int], list[int]]:
    """Every channel's confirmation by ``heliocal lamps status --json``, and the coils and
    discrete inputs read by mbpoll."""
    code, out, err = run_cli(["lamps", "--config", str(path), "status", "--json"])
    assert code == 0, err
    lit = {s["channel"]: s["lit"] for s in json.loads(out)["lamps"]}
    lamps = yaml.safe_load(path.read_text())["lamps"]
    mbpoll = shutil.which("mbpoll")
    if mbpoll is None:
        print("mbpoll is not installed (Debian package mbpoll, .ci/system-packages): the panel is read "
              "by heliocal only")
        return lit, [], []

    def bits(table: str) -> list[int]:
        out = subprocess.run([mbpoll, "-m", "tcp", "-p", str(lamps["port"]), "-a", "1", "-0", "-1",
                              "-t", table, "-r", "0", "-c", str(len(lamps["channels"])), "127.0.0.1"],
                             capture_output=True, text=True, check=True, timeout=scaled_s(10)).stdout
        return [int(line.split(":")[1]) for line in out.splitlines() if line.startswith("[")]

    return lit, bits("0"), bits("1")


def _assert_dark(fs, path, session: str, ended: str) -> None:
    lit, coils, inputs = _outside_view(path)
    assert lit and not any(lit.values())
    assert not any(coils) and not any(inputs)
    assert fs.plant.lit is None  # the plant's own lamps: nothing renders light
    rows = lamp_states(fs.field.store, session)
    assert {r["channel"] for r in rows} == set(lit)
    assert all(r["state"] == "dark" and r["ended"] == ended for r in rows)


def test_a_finished_campaign_and_a_night_leave_every_lamp_confirmed_dark(field):
    fs, path = field
    lamp = fs.field.cfg.calibration.light_source
    assert _outside_view(path)[0][lamp]  # the plant starts with its calibration lamp lit
    told = _Told()
    r = calibration_night(fs.book, Campaign(fs.field, CampaignOptions(name="n"), heliostat_ids=IDS,
                                            observers=[told]))
    assert r.status in ("finished", "partial")
    _assert_dark(fs, path, "n", r.status)
    assert NightBook(fs.field.store).nights()[-1].summary["lights_out"][0]["state"] == "dark"
    fs.plant.set_night(1)
    s = PlannedNight(fs.field, fs.book, "n/night-1", 1, heliostat_ids=IDS, observers=[told]).run()
    assert s.status in ("finished", "partial") and s.measured > 0 and s.lamps  # a lamp was lit, then
    _assert_dark(fs, path, "n/night-1", s.status)
    assert {x["state"] for x in s.lights_out} == {"dark"} and told.not_dark == []


class _Explodes(CampaignObserver):
    def measured(self, heliostat_id, measurement) -> None:
        raise RuntimeError("the operator's screen crashed")

    def run_recorded(self, campaign_id, run) -> None:
        raise RuntimeError("the operator's screen crashed")


def test_an_exception_ends_the_night_with_every_lamp_dark_and_recorded(field):
    fs, path = field
    with pytest.raises(RuntimeError, match="screen crashed"):
        calibration_night(fs.book, Campaign(fs.field, CampaignOptions(name="n"), heliostat_ids=IDS,
                                            observers=[_Explodes()]))
    _assert_dark(fs, path, "n", "aborted")
    night = NightBook(fs.field.store).nights()[-1]
    assert night.status == "aborted" and "screen crashed" in night.cause


def test_a_lamp_that_stays_lit_stops_with_one_line_and_is_recorded_and_told(field):
    fs, path = field
    lamp = fs.field.cfg.calibration.light_source
    fs.plant.lamp_panel.stuck_lit.add(lamp)  # a welded contactor: switched off, it stays lit
    told = _Told()
    with pytest.raises(LampNotDark) as err:
        calibration_night(fs.book, Campaign(fs.field, CampaignOptions(name="n"), heliostat_ids=IDS,
                                            observers=[told]))
    line = str(err.value)
    assert "\n" not in line and line.startswith(f"lamp {lamp} not confirmed dark at the end of n: ")
    assert err.value.exit_code == 1
    lit, coils, inputs = _outside_view(path)
    assert lit[lamp] and fs.plant.lamp_lit(lamp)
    channels = list(yaml.safe_load(path.read_text())["lamps"]["channels"])
    if inputs:  # the coil says off, the lamp's own input says lit
        assert coils[channels.index(lamp)] == 0 and inputs[channels.index(lamp)] == 1
    bad = lamps_not_dark(fs.field.store)
    assert [(b["session"], b["channel"], b["state"]) for b in bad] == [("n", lamp, "lit")]
    assert told.not_dark == [("n", lamp, "lit")]
    night = NightBook(fs.field.store).nights()[-1]
    assert lamp in night.cause  # the night's record says it too
    assert lamps_not_dark(fs.field.store, after_id=bad[-1]["id"]) == []  # an alarm list's next read
