"""A night that fails at its first lamp change (issue 45): whatever the lamps' fault — the
panel unreachable, a Modbus exception, a peer that is not a panel, lamps that never confirm
dark, a switch program that fails, hangs or cannot be executed — the night's record says how
it ended and why (never ``running``), its lamps' end states are recorded, and the error is
one line with exit status 1. A resumed night whose stored plan names a lamp no longer in the
configuration is refused in one line (exit 2), its record not left ``running``.

One simulated plant (one heliostat without a model: the night's first step is the lamp change
for the calibration lamp) serves every case; the faulty lamps replace its panel."""

from __future__ import annotations

import dataclasses
import socket
import stat

import pytest
import yaml

from controller.calibration.campaign.field import PanelLamps
from controller.calibration.campaign.runner import Campaign, CampaignOptions
from controller.calibration.night.planned import PlannedNight, calibration_night
from controller.calibration.night.planner import Geometry, PlanItem
from controller.commands.field import open_store
from controller.commands.simulated import simulated_field
from controller.config import CommandLamps, load_config
from controller.devices.lamp_drivers import open_lamp_panel
from controller.errors import HeliocalError
from controller.storage.lamp_states import lamp_states
from controller.storage.nights import NightBook
from simplant.settings import SimulationSettings
from tests.calibration.conftest import FAST, small_demo_data
from tests.conftest import run_cli, scaled_s
from tests.devices.tcp_peers import NotAPanel

IDS = ["H02"]


@pytest.fixture(scope="module")
def field(tmp_path_factory):
    """The demo plant with small cameras (as ``small_config``), once for the module."""
    tmp = tmp_path_factory.mktemp("night-fails")
    data = small_demo_data()
    config = tmp / "small.yaml"
    config.write_text(yaml.safe_dump(data))
    store = open_store(tmp / "c.db")
    settings = SimulationSettings(clock_speedup=FAST.clock_speedup, seed=5)
    with simulated_field(load_config(config), str(config), store, tmp / "sim", IDS, settings,
                         night=1, library=None) as fs:
        yield fs, tmp
    store.close()


def _script(folder, name: str, text: str, mode: int = 0o755) -> str:
    p = folder / name
    p.write_text(text)
    p.chmod(mode)
    return str(p)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _faulty(kind: str, fs, folder):
    """Lamps with fault ``kind`` for the channels of the plant's panel; (lamps section, what
    the night's cause must name). A NotAPanel peer is returned too, to be closed."""
    real = fs.plant.config.lamps
    channels = dict(real.channels)
    confirm = 2.0  # plant seconds (the plant's clock runs FAST)
    tcp = {"driver": "modbus-tcp", "host": "127.0.0.1", "timeout_s": scaled_s(0.2), "channels": channels,
           "confirm_timeout_s": confirm}

    def command(text: str, mode: int = 0o755, timeout: float = 5.0) -> CommandLamps:
        return CommandLamps(driver="command", command=(_script(folder, f"{kind}.sh", text, mode),),
                            channels=channels, timeout_s=scaled_s(timeout), confirm_timeout_s=confirm)

    if kind == "unreachable":
        dead = real.model_copy(update={"port": _free_port(), "timeout_s": scaled_s(0.2)})
        return dead, "cannot connect", None
    if kind == "modbus-exception":
        return real.model_copy(update={"unit": 9}), "Modbus exception 4", None
    if kind == "echo":
        peer = NotAPanel("echo").__enter__()
        return real.model_copy(update={**tcp, "port": peer.port}), "not a Modbus lamp panel", peer
    if kind == "inverted":  # every switch "succeeds", every status says lit
        return command("#!/bin/sh\nexit 0\n"), "did not confirm dark", None
    if kind == "program-fails":
        failing = command("#!/bin/sh\necho 'relay box offline' >&2\nexit 4\n")
        return failing, "exited 4: relay box offline", None
    if kind == "program-hangs":
        return command("#!/bin/sh\nsleep 300\n", timeout=0.3), "did not finish within", None
    if kind == "no-shebang":
        return command("echo switched\n"), "cannot be executed", None
    if kind == "not-executable":
        return command("#!/bin/sh\nexit 0\n", mode=stat.S_IRUSR | stat.S_IWUSR), "is not executable", None
    raise ValueError(kind)


KINDS = ["unreachable", "modbus-exception", "echo", "inverted", "program-fails", "program-hangs",
         "no-shebang", "not-executable"]


def _ended(outcome) -> str:
    """The one line the command prints, and its exit status 1."""
    if isinstance(outcome, HeliocalError):
        assert outcome.exit_code == 1
        return str(outcome)
    assert outcome.status == "aborted" and outcome.exit_code == 1
    return outcome.cause


@pytest.mark.parametrize("kind", KINDS)
def test_a_night_failing_at_its_first_lamp_change_records_why(field, kind):
    fs, folder = field
    section, said, peer = _faulty(kind, fs, folder)
    lamps = PanelLamps(open_lamp_panel(section), fs.field.time, section.confirm_timeout_s)
    plant = dataclasses.replace(fs.field, lamps=lamps)
    name = f"fails/{kind}"
    try:
        try:
            outcome = PlannedNight(plant, fs.book, name, 1, heliostat_ids=IDS).run()
        except HeliocalError as exc:
            outcome = exc
        line = _ended(outcome)
        assert "\n" not in line and said in line
        rec = next(n for n in NightBook(fs.field.store).nights() if n.name == name)
        assert rec.status == "aborted" and said in rec.cause
        ends = lamp_states(fs.field.store, name)
        assert {e["channel"] for e in ends} == set(section.channels)  # every lamp's end recorded
        assert fs.field.store.measurements() == []  # nothing measured under a lamp not seen lit
    finally:
        lamps.close()
        if peer is not None:
            peer.__exit__(None, None, None)


def test_a_calibration_campaign_failing_at_its_first_lamp_records_why(field):
    fs, folder = field
    section, said, _ = _faulty("program-fails", fs, folder)
    lamps = PanelLamps(open_lamp_panel(section), fs.field.time, section.confirm_timeout_s)
    plant = dataclasses.replace(fs.field, lamps=lamps)
    campaign = Campaign(plant, CampaignOptions(name="fails-calibration"), heliostat_ids=IDS)
    with pytest.raises(HeliocalError) as e:
        calibration_night(fs.book, campaign)
    assert e.value.exit_code == 1 and said in str(e.value) and "\n" not in str(e.value)
    rec = next(n for n in NightBook(fs.field.store).nights() if n.name == "fails-calibration")
    assert rec.status == "aborted" and said in rec.cause


def test_resuming_a_plan_whose_lamp_left_the_configuration_is_refused_in_one_line(field):
    fs, _ = field
    book, name = fs.book, "fails/stale-plan"
    rec, _ = book.open_night(name, "planned")
    book.record_plan([PlanItem("H02", name, Geometry("lamp-gone", (0.0, 0.0, 30.0), (0, 0), (0, 0)),
                               1, 0.1, 1.0, 0.5)])
    book.finish_night(rec.id, "interrupted", "stopped by the operator; rerun to resume", {})
    writes = len(fs.plant.lamp_panel.writes)
    with pytest.raises(HeliocalError) as e:
        PlannedNight(fs.field, book, name, 1, heliostat_ids=IDS).run()
    assert e.value.exit_code == 2 and "\n" not in str(e.value)
    assert str(e.value).endswith(f"night {name} was planned with lamp 'lamp-gone', no longer a lamp of "
                                 "light_sources; put it back to resume that night")
    rec = next(n for n in NightBook(fs.field.store).nights() if n.name == name)
    assert rec.status == "aborted" and "'lamp-gone'" in rec.cause
    assert not any(on for _, on in fs.plant.lamp_panel.writes[writes:])  # nothing lit for it


class _FullDisk(NightBook):
    """The store fails while the night is being ended (after its lamps were switched off)."""

    def record_heliostats(self, night_id: int, rows: list[dict]) -> None:
        raise OSError(28, "No space left on device")


def test_a_night_whose_ending_fails_is_still_recorded_with_why(field):
    fs, folder = field
    section, said, _ = _faulty("program-fails", fs, folder)
    lamps = PanelLamps(open_lamp_panel(section), fs.field.time, section.confirm_timeout_s)
    plant = dataclasses.replace(fs.field, lamps=lamps)
    with pytest.raises(OSError, match="No space left"):
        PlannedNight(plant, _FullDisk(fs.field.store), "fails/ending", 1, heliostat_ids=IDS).run()
    rec = next(n for n in NightBook(fs.field.store).nights() if n.name == "fails/ending")
    assert rec.status == "aborted" and said in rec.cause
    assert rec.cause.endswith("ending it failed: OSError: [Errno 28] No space left on device")


def test_campaign_list_shows_a_night_that_ended_before_any_campaign_with_its_cause(field):
    fs, folder = field
    section, said, _ = _faulty("no-shebang", fs, folder)
    lamps = PanelLamps(open_lamp_panel(section), fs.field.time, section.confirm_timeout_s)
    name = "fails/listed"
    with pytest.raises(HeliocalError):
        PlannedNight(dataclasses.replace(fs.field, lamps=lamps), fs.book, name, 1, heliostat_ids=IDS).run()
    code, out, _ = run_cli(["campaign", "list", "--db", str(fs.field.store.path)])
    lines = out.splitlines()
    at = next(i for i, line in enumerate(lines) if f": {name} (planned), aborted" in line)
    assert code == 0 and lines[at + 1].startswith("    LampCommandError: lamps.command: ")
    assert len(lines[at + 1]) <= 120  # cut to the width (a long program path); --long gives it whole
    code, out, _ = run_cli(["campaign", "list", "--db", str(fs.field.store.path), "--long"])
    assert code == 0 and said in next(line for line in out.splitlines() if f": {name} (planned)" in line)
