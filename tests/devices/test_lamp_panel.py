"""The Modbus lamp-panel driver against the simulated plant's panel (a pymodbus server on
127.0.0.1 whose coils switch the plant's lamps). The plant's own lamp state — what its cameras
render with — is the truth the tests check, not what the driver reports; mbpoll (libmodbus)
reads and writes the panel independently of pymodbus."""

from __future__ import annotations

import shutil
import socket
import subprocess
import threading
import time

import pytest

from controller.config import ModbusRtuLamps, ModbusTcpLamps
from controller.devices.drive import DriveLimits
from controller.devices.factory import LinkPool
from controller.devices.lamp_drivers import open_lamp_panel
from controller.devices.lamp_panel import (
    LampError,
    LampNotConfirmed,
    light_only,
    lights_out,
    set_and_confirm,
)
from controller.devices.plant_time import PlantTime
from controller.errors import InputError
from simplant.devices.lamp_panel import SimLampPanel
from simplant.plant import SimulatedPlant, load_config_data
from tests.calibration.conftest import REPO
from tests.conftest import scaled_s
from tests.devices.tcp_peers import KINDS, NotAPanel

FIDUCIALS = "fiducials:tower-lower"


@pytest.fixture(scope="module")
def field(tmp_path_factory):
    """The demo plant with one serial and one Modbus TCP heliostat, its panel and config."""
    plant = SimulatedPlant(load_config_data(REPO / "configs" / "demo.yaml"),
                           tmp_path_factory.mktemp("plant"), heliostat_ids=["H01", "H13"], seed=4)
    cfg = plant.start()
    yield plant, cfg
    plant.stop()


@pytest.fixture
def panel(field):
    plant, cfg = field
    plant.lamp_panel.no_confirm.clear()
    plant.lamp_panel.no_light.clear()
    with open_lamp_panel(cfg.lamps) as p:
        yield p
        lights_out(p, time=_time(), timeout_s=scaled_s(2.0))


def _time() -> PlantTime:
    return PlantTime(poll_s=scaled_s(0.01))


def test_the_plant_writes_a_panel_with_every_lamp_and_registering_target(field):
    plant, cfg = field
    lamps = [s.id for s in cfg.light_sources if s.kind == "lamp"]
    assert cfg.lamps.driver == "modbus-tcp" and cfg.lamps.host == "127.0.0.1"
    assert cfg.lamps.port == plant.lamp_panel.port
    assert list(cfg.lamps.channels) == [*lamps, "fiducials:tower-target", FIDUCIALS]
    assert sorted(cfg.lamps.channels.values()) == list(range(len(lamps) + 2))


def test_light_only_lights_one_lamp_after_the_others_are_dark(field, panel):
    plant, _ = field
    set_and_confirm(panel, "lamp-east", True, time=_time(), timeout_s=scaled_s(2.0))
    assert plant.lit == "lamp-east"
    start = len(plant.lamp_panel.writes)
    light_only(panel, "lamp-west", time=_time(), timeout_s=scaled_s(2.0))
    assert plant.lit == "lamp-west" and not plant.lamp_lit("lamp-east")
    writes = plant.lamp_panel.writes[start:]
    assert writes[-1] == ("lamp-west", True)
    assert all(not on for _, on in writes[:-1]) and ("lamp-east", False) in writes
    assert not any(name.startswith("fiducials:") for name, _ in writes)  # registration's own
    states = {s.channel: s for s in panel.states()}
    assert states["lamp-west"].to_json() == {"channel": "lamp-west", "commanded": True, "lit": True}
    assert [c for c, s in states.items() if s.lit or s.commanded] == ["lamp-west"]


def test_fiducials_and_lights_out(field, panel):
    plant, _ = field
    set_and_confirm(panel, FIDUCIALS, True, time=_time(), timeout_s=scaled_s(2.0))
    light_only(panel, "lamp", time=_time(), timeout_s=scaled_s(2.0))
    assert plant.cameras["tower-lower"].fiducials_lit and not plant.cameras["tower-target"].fiducials_lit
    lights_out(panel, time=_time(), timeout_s=scaled_s(2.0))
    assert plant.lit is None and not plant.cameras["tower-lower"].fiducials_lit
    assert not any(s.lit or s.commanded for s in panel.states())


def test_a_lamp_that_does_not_confirm_stops_with_a_line_naming_it(field, panel):
    plant, cfg = field
    plant.lamp_panel.no_confirm.add("lamp-west")
    clock = plant.clock
    t0 = clock()
    with pytest.raises(LampNotConfirmed, match=r"^lamp lamp-west did not confirm lit within 10 s$") as e:
        # plant time: the plant's clock (sped up), the configured 10 plant seconds
        light_only(panel, "lamp-west", time=PlantTime(now=clock, sleep=clock.sleep, poll_s=0.5),
                   timeout_s=cfg.lamps.confirm_timeout_s)
    assert clock() - t0 >= cfg.lamps.confirm_timeout_s
    assert e.value.exit_code == 1 and e.value.channels == ("lamp-west",)
    assert plant.lit is None  # every other lamp went dark, and this one never lit
    assert {s.channel: s.commanded for s in panel.states()}["lamp-west"] is True


def test_a_lamp_that_confirms_without_light_is_seen_only_by_the_plant(field, panel):
    plant, _ = field
    plant.lamp_panel.no_light.add("lamp-low")
    light_only(panel, "lamp-low", time=_time(), timeout_s=scaled_s(2.0))
    assert panel.confirmed("lamp-low") and plant.lit is None


def test_an_unknown_channel_is_refused_before_anything_is_sent(field, panel):
    plant, _ = field
    before = len(plant.lamp_panel.writes)
    for call in (lambda: panel.switch("lamp-north", True), lambda: panel.confirmed("lamp-north"),
                 lambda: set_and_confirm(panel, "lamp-north", True, time=_time(), timeout_s=1.0),
                 lambda: light_only(panel, "lamp-north", time=_time(), timeout_s=1.0)):
        with pytest.raises(InputError, match="no lamp channel 'lamp-north' in lamps.channels"):
            call()
    assert len(plant.lamp_panel.writes) == before


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_no_panel_no_answer_and_a_refused_unit_are_one_line_each(field):
    _, cfg = field
    timeout = scaled_s(0.2)
    port = _free_port()
    dead = ModbusTcpLamps(driver="modbus-tcp", host="127.0.0.1", port=port, timeout_s=timeout,
                          channels={"lamp-west": 1})
    with open_lamp_panel(dead) as p, pytest.raises(LampError) as e:
        p.switch("lamp-west", True)
    assert str(e.value) == (f"lamp panel modbus-tcp 127.0.0.1:{port} unit 1: cannot connect for "
                            "writing coil 1 of lamp lamp-west")
    with socket.socket() as mute:  # accepts, never answers
        mute.bind(("127.0.0.1", 0))
        mute.listen()
        port = mute.getsockname()[1]
        silent = dead.model_copy(update={"port": port})
        with open_lamp_panel(silent) as p, pytest.raises(LampError, match=(
                rf"^lamp panel modbus-tcp 127.0.0.1:{port} unit 1: no answer to reading discrete "
                r"input 1 of lamp lamp-west$")):
            p.confirmed("lamp-west")
    wrong_unit = cfg.lamps.model_copy(update={"unit": 9})
    with open_lamp_panel(wrong_unit) as p, pytest.raises(LampError, match=(
            r"unit 9: reading coil 0 of lamp lamp refused with Modbus exception 4 "
            r"\(server device failure\)$")):
        p.states()


def test_mbpoll_reads_the_coils_and_inputs_and_its_coil_write_lights_the_lamp(field, panel):
    mbpoll = shutil.which("mbpoll")
    if mbpoll is None:
        pytest.skip("mbpoll is not installed (Debian package mbpoll, .ci/system-packages)")
    plant, cfg = field
    n = len(cfg.lamps.channels)
    west = cfg.lamps.channels["lamp-west"]

    def run(*args: str, values: tuple[str, ...] = ()) -> str:
        return subprocess.run([mbpoll, "-m", "tcp", "-p", str(cfg.lamps.port), "-a", "1", "-0", "-1",
                               *args, "127.0.0.1", *values], capture_output=True, text=True, check=True,
                              timeout=scaled_s(10)).stdout

    def bits(table: str) -> list[int]:
        out = run("-t", table, "-r", "0", "-c", str(n))
        return [int(line.split(":")[1]) for line in out.splitlines() if line.startswith("[")]

    light_only(panel, "lamp-east", time=_time(), timeout_s=scaled_s(2.0))
    east = cfg.lamps.channels["lamp-east"]
    assert bits("0") == bits("1") == [int(i == east) for i in range(n)]
    run("-t", "0", "-r", str(west), values=("1",))  # FC05 from libmodbus
    assert plant.lamp_lit("lamp-west") and panel.confirmed("lamp-west")
    assert bits("1") == [int(i in (east, west)) for i in range(n)]


def test_the_rtu_driver_through_an_rtu_framed_panel(field):
    plant, cfg = field
    sim = SimLampPanel(plant, dict(cfg.lamps.channels))
    port = sim.start(rtu_framing=True)
    try:
        rtu = ModbusRtuLamps(driver="modbus-rtu", device=f"socket://127.0.0.1:{port}",
                             channels=dict(cfg.lamps.channels), timeout_s=scaled_s(1.0))
        with open_lamp_panel(rtu) as p:
            light_only(p, "lamp-far-west", time=_time(), timeout_s=scaled_s(2.0))
            assert plant.lit == "lamp-far-west" and p.confirmed("lamp-far-west")
            lights_out(p, time=_time(), timeout_s=scaled_s(2.0))
        assert plant.lit is None
    finally:
        sim.stop()


def test_the_panel_and_the_modbus_drive_server_stop_independently(tmp_path):
    plant = SimulatedPlant(load_config_data(REPO / "configs" / "demo.yaml"), tmp_path / "p",
                           heliostat_ids=["H13"], seed=5)
    cfg = plant.start()
    try:
        with LinkPool() as pool, open_lamp_panel(cfg.lamps) as p:
            h13 = cfg.heliostat("H13")
            drive = pool.drive(h13.link, DriveLimits.from_axes(h13.axes))
            plant.modbus.pause("tcp")  # the drive server goes: the panel still answers
            set_and_confirm(p, "lamp-west", True, time=_time(), timeout_s=scaled_s(2.0))
            plant.modbus.resume("tcp")
            plant.lamp_panel.stop()  # the panel goes: the drive still answers
            assert drive.status().az_steps is not None
            with pytest.raises(LampError, match="lamp panel modbus-tcp"):
                p.confirmed("lamp-west")
    finally:
        plant.stop()


def test_the_panel_serves_several_clients_at_once(field):
    _, cfg = field
    errors: list[Exception] = []

    def worker(channel: str) -> None:
        try:
            with open_lamp_panel(cfg.lamps) as p:
                for _ in range(20):
                    p.states()
                set_and_confirm(p, channel, False, time=_time(), timeout_s=scaled_s(2.0))
        except Exception as exc:  # reported below
            errors.append(exc)

    threads = [threading.Thread(target=worker, args=(c,)) for c in ("fiducials:tower-target", FIDUCIALS)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []


@pytest.mark.parametrize("kind", KINDS)
def test_a_peer_that_is_not_a_lamp_panel_is_refused_in_one_line(kind):
    timeout = scaled_s(0.2)
    with NotAPanel(kind) as peer:
        cfg = ModbusTcpLamps(driver="modbus-tcp", host="127.0.0.1", port=peer.port, timeout_s=timeout,
                             channels={"lamp": 0, "lamp-west": 1, "lamp-east": 2})
        for call in (lambda p: p.states(), lambda p: p.switch("lamp-west", True),
                     lambda p: p.confirmed("lamp-east")):
            t0 = time.monotonic()
            with open_lamp_panel(cfg) as p, pytest.raises(LampError) as e:
                call(p)
            line = str(e.value)
            assert line.startswith(f"lamp panel modbus-tcp 127.0.0.1:{peer.port} unit 1: ")
            assert "\n" not in line
            if kind in ("echo", "fc05", "two-bytes", "padding"):  # it answered, not as a panel does
                assert "not a Modbus lamp panel" in line
            assert time.monotonic() - t0 < 4 * timeout + scaled_s(1)  # two attempts, each bounded
