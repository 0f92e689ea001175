"""The plant's view of heliocal end to end, on a simulated plant over real transports (drives
on ptys and Modbus TCP, the lamp panel on Modbus TCP): ``heliocal opcua`` as a separate process
read and driven by an independent OPC UA client (node-opcua) and by asyncua's with
Basic256Sha256 sign & encrypt; a lamp that does not confirm dark raised as an alarm that the
command line, the console and OPC UA show and whose acknowledgement records who; the console
refusing a viewer's night and auditing an operator's."""

from __future__ import annotations

import json
import queue
import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml

from controller.calibration.records import RunRecord
from controller.config import config_sha256
from controller.devices.lamp_panel import open_lamp_panel, set_and_confirm
from controller.devices.plant_time import WALL
from controller.storage.db import CampaignStore
from controller.storage.nights import NightBook
from controller.storage.users import Accounts
from simplant.plant import SimulatedPlant, load_config_data
from simplant.settings import SimulationSettings
from tests.conftest import run_cli, scaled_s
from tests.console.conftest import small_config_file
from tests.plant.conftest import record_models

pytestmark = pytest.mark.xdist_group("plant-integration")  # one plant and server, tests in order

REPO = Path(__file__).resolve().parents[2]
NODE_CLIENT = Path(__file__).parent / "node_client"
IDS = ["H02", "H14"]  # serial and Modbus TCP drives
PASSWORDS = {"alice": ("operator", "alice-operates"), "victor": ("viewer", "victor-views")}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ServerProcess:
    """``heliocal opcua`` in a subprocess, until :meth:`stop` (SIGTERM)."""

    def __init__(self, config: Path, db: Path) -> None:
        self.endpoint = f"opc.tcp://127.0.0.1:{_free_port()}/heliocal"
        self.p = subprocess.Popen([sys.executable, "-m", "controller.cli", "opcua", "--config", str(config),
                                   "--db", str(db), "--endpoint", self.endpoint, "--poll", "0.2"],
                                  cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.lines: queue.Queue[str] = queue.Queue()
        self.stderr: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()
        deadline = time.monotonic() + scaled_s(60)
        while time.monotonic() < deadline:
            try:
                if "serving" in self.lines.get(timeout=1.0):
                    return
            except queue.Empty:
                if self.p.poll() is not None:
                    break
        self.stop()
        raise AssertionError("heliocal opcua did not start:\n" + "".join(self.stderr))

    def _read(self) -> None:
        for line in self.p.stderr:
            self.stderr.append(line)
            self.lines.put(line)

    def stop(self) -> int:
        if self.p.poll() is None:
            self.p.terminate()
        return self.p.wait(scaled_s(30))


@pytest.fixture(scope="module")
def plant(tmp_path_factory):
    """(simulated plant, its config file as a user would point heliocal at it, database,
    OPC UA server process)."""
    tmp = tmp_path_factory.mktemp("plant")
    source = small_config_file(tmp / "small.yaml", pipeline_depth=1)
    with SimulatedPlant(load_config_data(source), tmp / "run", heliostat_ids=IDS,
                        settings=SimulationSettings(clock_speedup=50.0), source=str(source)) as sim:
        sim.start()
        data = dict(sim.data, heliostats=[h for h in sim.data["heliostats"] if h["id"] in IDS])
        config = tmp / "field.yaml"
        config.write_text(yaml.safe_dump(data, sort_keys=False))
        db = tmp / "c.db"
        with CampaignStore(db) as store:
            for name, (role, password) in PASSWORDS.items():
                Accounts(store).add(name, role, password, by="test")
        record_models(db, config, ["H02"], seed=3)
        server = ServerProcess(config, db)
        try:
            yield sim, config, db, server
        finally:
            assert server.stop() == 0, "".join(server.stderr)
            assert "stopped" in server.stderr[-1]


def _lamps_lit(config: Path) -> dict[str, bool]:
    code, out, err = run_cli(["lamps", "--config", str(config), "status", "--json"])
    assert code == 0, err
    return {s["channel"]: s["lit"] for s in json.loads(out)["lamps"]}


def _light(config: Path, lamp: str) -> None:
    from controller.config import load_config

    with open_lamp_panel(load_config(config).lamps) as panel:
        set_and_confirm(panel, lamp, True, time=WALL, timeout_s=scaled_s(5))


def _audit(db: Path) -> list[dict]:
    code, out, err = run_cli(["audit", "--db", str(db), "--json"])
    assert code == 0, err
    return json.loads(out)


def _node(server: ServerProcess, user: str, security: str, *steps: str, tmp: Path) -> subprocess.Popen:
    if not (NODE_CLIENT / "node_modules" / "node-opcua-client").is_dir() or shutil.which("node") is None:
        pytest.skip("node-opcua is not installed (make .venv/.installed runs .ci/node-packages: needs node "
                    "and npm)")
    argv = ["node", str(NODE_CLIENT / "client.js"), server.endpoint, user, PASSWORDS[user][1], security,
            *steps]
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={"PATH": "/usr/bin:/bin:/usr/local/bin", "CLIENT_PKI": str(tmp / "pki"),
                                 "HOME": str(tmp)})


def _json_lines(text: str) -> list[dict]:
    """The client's JSON lines (node-opcua logs a line of its own when it makes its certificate)."""
    return [json.loads(x) for x in text.splitlines() if x.startswith("{")]


def _record_night(db: Path, config: Path, name: str, lines) -> None:
    """A calibration night of IDS recorded as the runner records it, one heliostat at a time,
    each once the client has seen the progress before it."""
    with CampaignStore(db) as store:
        book = NightBook(store)
        rec, _ = book.open_night(name, "calibration")
        cid, _ = store.open_campaign(name, config_path=str(config), config_sha256=config_sha256(config),
                                     light_source="lamp", target="tower-target", queue=IDS)
        for k, hid in enumerate(IDS):
            store.record_run(cid, RunRecord(hid, k, "calibrated", "done", 2, 0.0, 1.0))
            want = (k + 1) / len(IDS)
            for line in lines:
                if line.get("value") == want:
                    break
        store.finish_campaign(cid, "finished")
        book.finish_night(rec.id, "finished", None, {})
        store.campaign_lock.release()


def test_an_independent_client_browses_reads_subscribes_and_switches_the_lamps_off(plant, tmp_path):
    sim, config, db, server = plant
    lamp = sim.config.calibration.light_source
    _light(config, lamp)
    assert _lamps_lit(config)[lamp] and sim.lit == lamp
    p = _node(server, "alice", "none", "browse", "read:Heliostats/H02/State",
              "read:Heliostats/H02/ModelVersion", f"watch:Night/Progress:1:{scaled_s(30):g}",
              "call:Lamps/AllOff", tmp=tmp_path)
    lines = (json.loads(x) for x in iter(p.stdout.readline, "") if x.startswith("{"))
    seen = []
    for line in lines:
        seen.append(line)
        if line.get("subscribed"):
            break
    _record_night(db, config, "field-night-0", (seen.append(x) or x for x in lines))
    rest, err = p.communicate(timeout=scaled_s(60))
    seen += _json_lines(rest)
    assert p.returncode == 0, (seen, err)
    browse = next(s for s in seen if s["step"] == "browse")
    assert browse["heliocal"] == ["Field", "Heliostats", "Targets", "Lamps", "Night", "Alarms", "Models"]
    assert browse["heliostats"] == IDS
    reads = {s["path"]: s["value"] for s in seen if s["step"] == "read"}
    assert reads == {"Heliostats/H02/State": "calibrated", "Heliostats/H02/ModelVersion": 1}
    progress = [s["value"] for s in seen if s["step"] == "watch" and "value" in s]
    assert 0.5 in progress and progress[-1] == 1  # the night's progress as it was recorded
    assert next(s for s in seen if s["step"] == "call")["status"] == "Good"
    assert not any(_lamps_lit(config).values()) and sim.lit is None  # every lamp dark (the panel's inputs)
    assert ("alice", "lamps.off", "all") in [(r["user"], r["action"], r["target"]) for r in _audit(db)]


def test_a_viewer_calling_all_off_gets_bad_user_access_denied(plant, tmp_path):
    sim, config, db, server = plant
    lamp = sim.config.calibration.light_source
    _light(config, lamp)
    p = _node(server, "victor", "sign-encrypt", "read:Heliostats/H14/State", "call:Lamps/AllOff",
              tmp=tmp_path)
    out, err = p.communicate(timeout=scaled_s(60))
    seen = _json_lines(out)
    assert p.returncode == 0, (seen, err)
    assert seen == [{"step": "read", "path": "Heliostats/H14/State", "status": "Good", "value": "calibrated"},
                    {"step": "call", "path": "Lamps/AllOff", "status": "BadUserAccessDenied"}]
    assert _lamps_lit(config)[lamp]  # nothing was switched
    denied = [r for r in _audit(db) if r["action"] == "denied"]
    assert [(r["user"], r["target"]) for r in denied] == [("victor", "AllOff lamps")]
