"""The console's JSON API through Starlette's TestClient, over a real simulated plant in this
process (real serial and Modbus drivers, simulated camera): safety and security rules."""

from __future__ import annotations

import asyncio
import threading
import time

import pytest
from starlette.testclient import TestClient

from controller.commands.simulated import plant_field
from controller.console.app import TOKEN_HEADER, create_app
from controller.console.backend import Console, PlantHooks
from controller.console.events import EventBus
from controller.devices.drive import AxisLimits, DriveLimits
from controller.devices.factory import LinkPool
from controller.storage.db import CampaignStore
from controller.storage.lock import CampaignLock, DatabaseBusy
from simplant.plant import SimulatedPlant, load_config_data
from simplant.settings import SimulationSettings
from tests.conftest import scaled_s
from tests.console.conftest import small_config_file

# The tests share one console (module fixture) and read what the earlier ones did (campaigns
# api-pause and api-abort): one worker runs them all, in order (make test: --dist loadgroup).
pytestmark = pytest.mark.xdist_group("console-api")

TOKEN = "s3cret-token-for-tests"
JSON = {"Content-Type": "application/json"}


@pytest.fixture(scope="module")
def plant_console(tmp_path_factory):
    """A console (with a token, as on a non-loopback bind) over H02 (serial) and H14 (Modbus TCP)."""
    tmp = tmp_path_factory.mktemp("api")
    cfg_path = small_config_file(tmp / "small.yaml", pipeline_depth=1)  # one cycle at a time: pause shows
    ids = ["H02", "H14"]
    with SimulatedPlant(load_config_data(cfg_path), tmp / "run", heliostat_ids=ids,
                        settings=SimulationSettings(clock_speedup=50.0), source=str(cfg_path)) as plant:
        plant.start()
        hooks = PlantHooks(safety=plant.safety.report, set_night=plant.set_night, label="simulated plant")
        with LinkPool(timeout_s=0.5, retries=2) as pool, CampaignStore(tmp / "c.db") as store:
            console = Console(plant_field(plant, cfg_path, store, pool), heliostat_ids=ids, hooks=hooks,
                              work_dir=tmp / "work")
            app = create_app(console, token=TOKEN)
            with TestClient(app, base_url="http://console.test") as client:
                yield console, client
            console.close()


def _steps(console, hid):
    st = console.drive(hid).status()
    return st.az_steps, st.el_steps


def _post(client, path, body=None, token=TOKEN, **headers):
    h = {**JSON, **headers}
    if token is not None:
        h[TOKEN_HEADER] = token
    return client.post(path, json=body or {}, headers=h)


@pytest.mark.parametrize("body,status,words", [
    (b"[" * 100_000 + b"]" * 100_000, 413, "too large"),  # 200 kB, deeply nested
    (b'{"a": ' * 5000 + b"1" + b"}" * 5000, 400, "nested 5000 levels deep"),  # within the size limit
    (b'{"az_steps": 100, "az_steps": 0, "el_steps": 0}', 400, "duplicate key 'az_steps'"),
    (b'{"az_steps": 100, "el_steps": ', 400, "invalid JSON"),
    (b"\xff\xfe{}", 400, "not UTF-8"),
    (b'{"az_steps": 1e999, "el_steps": 0}', 400, ""),
])
def test_request_bodies_are_bounded_and_refused_with_json(plant_console, body, status, words):
    """Size, nesting, duplicate keys and encoding are checked before the body is parsed: a 4xx
    with a JSON message, never a 500 (the jog is not sent)."""
    console, client = plant_console
    before = _steps(console, "H02")
    r = client.post("/api/heliostats/H02/jog", content=body, headers={**JSON, TOKEN_HEADER: TOKEN})
    assert r.status_code == status, r.text
    assert r.json()["ok"] is False and words in r.json()["error"]
    assert _steps(console, "H02") == before


def test_a_streamed_body_without_length_is_cut_at_the_limit(plant_console):
    console, client = plant_console

    def chunks():
        for _ in range(100):
            yield b" " * 4096
    r = client.post("/api/heliostats/H02/jog", content=chunks(), headers={**JSON, TOKEN_HEADER: TOKEN})
    assert r.status_code == 413 and "too large" in r.json()["error"]


def test_state_change_needs_the_token(plant_console):
    console, client = plant_console
    before = _steps(console, "H02")
    for token in (None, "wrong-token-xxxxxxxx", TOKEN + "x", ""):
        r = _post(client, "/api/heliostats/H02/jog", {"az_steps": 100, "el_steps": 0}, token=token)
        assert r.status_code == 401 and TOKEN_HEADER in r.json()["error"]
    r = _post(client, "/api/campaign/start", {"name": "nope"}, token=None)
    assert r.status_code == 401
    time.sleep(0.2)
    assert _steps(console, "H02") == before and console.store.campaigns() == []
    assert not console.store.campaign_lock.held
    r = _post(client, "/api/heliostats/H02/jog", {"az_steps": 100, "el_steps": 0})
    assert r.status_code == 200, r.text
    assert _steps(console, "H02") == (before[0] + 100, before[1])
    assert r.json()["result"]["az_steps"] == before[0] + 100
    assert _post(client, "/api/heliostats/H02/park").status_code == 200


def test_no_state_change_on_get_nor_without_json(plant_console):
    console, client = plant_console
    before = _steps(console, "H02")
    assert client.get("/api/heliostats/H02/jog").status_code == 405
    assert client.get("/api/campaign/start").status_code == 405
    r = client.post("/api/heliostats/H02/jog", content="az_steps=100&el_steps=0",
                    headers={"Content-Type": "application/x-www-form-urlencoded", TOKEN_HEADER: TOKEN})
    assert r.status_code == 415
    r = _post(client, "/api/heliostats/H02/jog", {"az_steps": 100, "el_steps": 0}, Origin="http://evil.example")
    assert r.status_code == 403
    assert _steps(console, "H02") == before


def test_soft_limits_refused_before_sending(plant_console):
    console, client = plant_console
    before = _steps(console, "H14")
    r = _post(client, "/api/heliostats/H14/move", {"az_steps": 10_000_000, "el_steps": 600})
    body = r.json()
    assert r.status_code == 400 and body["kind"] == "soft_limits" and body["outcome"] == "not_executed"
    assert "nothing was sent" in body["error"]
    r = _post(client, "/api/heliostats/H14/move", {"az_steps": "10", "el_steps": 600})
    assert r.status_code == 400 and "integer" in r.json()["error"]
    assert _steps(console, "H14") == before


def test_firmware_refusal_shown(plant_console):
    """A target inside the configuration's soft limits but outside the firmware's: the
    controller sends it, the firmware refuses it (NAK), nothing moves."""
    console, client = plant_console
    drive = console.drive("H14")
    before = _steps(console, "H14")
    original = drive.get_limits()
    narrow = DriveLimits(AxisLimits(original.az.min_steps, before[0] + 1000), original.el)
    drive.set_limits(narrow)
    try:
        r = _post(client, "/api/heliostats/H14/move", {"az_steps": before[0] + 2000, "el_steps": before[1]})
    finally:
        drive.set_limits(original)
    body = r.json()
    assert r.status_code == 409 and body["kind"] == "firmware_refused", body
    assert body["outcome"] == "not_executed"
    assert _steps(console, "H14") == before
    assert console.holder() is None  # a refused command does not claim the target


def test_one_beam_per_target_and_the_campaign_lock(plant_console):
    console, client = plant_console
    assert _post(client, "/api/heliostats/H02/aim").status_code == 200  # H02's beam is on the target
    before = _steps(console, "H14")
    r = _post(client, "/api/heliostats/H14/jog", {"az_steps": 50, "el_steps": 0})
    assert r.status_code == 409 and "H02" in r.json()["error"]
    assert _post(client, "/api/campaign/start", {"name": "blocked"}).status_code == 409
    assert _steps(console, "H14") == before
    with pytest.raises(DatabaseBusy, match="console"):  # what `heliocal campaign run` would meet
        CampaignLock(console.store.path).acquire()
    assert _post(client, "/api/heliostats/H02/park").status_code == 200
    assert not console.store.campaign_lock.held  # nothing left to park: the lock is free again

    cli = CampaignLock(console.store.path)  # a CLI campaign on the same database
    cli.acquire()
    try:
        r = _post(client, "/api/heliostats/H14/jog", {"az_steps": 50, "el_steps": 0})
        assert r.status_code == 409 and "in use" in r.json()["error"]
        assert _post(client, "/api/campaign/start", {"name": "blocked"}).status_code == 409
    finally:
        cli.release()
    assert _steps(console, "H14") == before and console.store.campaigns() == []


def _wait_for(cond, seconds: float, what: str) -> None:
    deadline = time.monotonic() + scaled_s(seconds)
    while not cond():
        assert time.monotonic() < deadline, f"waited {scaled_s(seconds):g} s for {what}"
        time.sleep(0.02)


def test_campaign_pause_holds_the_queue(plant_console):
    console, client = plant_console
    assert _post(client, "/api/campaign/start", {"name": "api-pause"}).status_code == 200
    _wait_for(lambda: console.campaign.states, 30, "the first cycle to start")
    assert _post(client, "/api/campaign/pause").json()["paused"]
    _wait_for(lambda: len(console.campaign.recorded) == 1, 60, "the first heliostat")
    snap = client.get("/api/campaign").json()
    first, second = snap["queue"]
    assert first["status"] == "calibrated" and second["state"] == "queued"  # held while paused
    assert snap["running"] and snap["paused"]
    assert _post(client, "/api/campaign/resume").status_code == 200
    _wait_for(lambda: not console.campaign.running, 60, "the end of the campaign")
    snap = client.get("/api/campaign").json()
    assert snap["outcome"]["status"] == "finished" and snap["progress"]["done"] == 2
    assert [q["status"] for q in snap["queue"]] == ["calibrated", "calibrated"]


def test_campaign_abort_parks_and_records_interrupted(plant_console):
    console, client = plant_console
    r = _post(client, "/api/campaign/start", {"name": "api-abort"})
    assert r.status_code == 200 and r.json()["running"]
    r = _post(client, "/api/heliostats/H02/jog", {"az_steps": 10, "el_steps": 0})
    assert r.status_code == 409 and "campaign api-abort is running" in r.json()["error"]
    deadline = time.monotonic() + scaled_s(30.0)
    while not console.campaign.on_target() and time.monotonic() < deadline:
        time.sleep(0.02)  # abort while a beam is on the target
    assert _post(client, "/api/campaign/abort").status_code == 200
    deadline = time.monotonic() + scaled_s(60.0)
    while console.campaign.running and time.monotonic() < deadline:
        time.sleep(0.05)
    snap = client.get("/api/campaign").json()
    assert snap["outcome"]["status"] == "interrupted", snap
    camp = console.store.campaign_by_name("api-abort")
    assert camp.status == "interrupted"
    pointing = console.session("H02").pointing
    for hid in ("H02", "H14"):
        st = console.drive(hid).status()
        assert not st.moving
        if hid == "H02":
            assert not pointing.beam_on_target(st.az_steps, st.el_steps)
    assert snap["beam_safety"]["plant"]["violations"] == 0
    assert not console.store.campaign_lock.held


def test_a_planned_night_started_watched_and_stopped_from_the_console(plant_console):
    console, client = plant_console
    r = _post(client, "/api/night/start", {"heliostats": ["H02"]})
    assert r.status_code == 200 and r.json()["running"] and r.json()["night"] >= 1
    assert _post(client, "/api/campaign/start", {"name": "during-night"}).status_code == 409
    assert _post(client, "/api/heliostats/H14/jog", {"az_steps": 10, "el_steps": 0}).status_code == 409
    _wait_for(lambda: client.get("/api/night").json()["log"], 60, "the night's first progress line")
    _wait_for(lambda: console.night.snapshot()["lamp"] is not None, 60, "the night's first lamp")
    assert _post(client, "/api/night/stop").status_code == 200
    _wait_for(lambda: not console.night.running, 60, "the end of the night")
    snap = client.get("/api/night").json()
    assert snap["outcome"]["status"] == "interrupted", snap
    assert not any(s.lit for s in console.field.lamps.panel.states())  # every lamp off
    st = console.drive("H02").status()
    assert not st.moving and not console.store.campaign_lock.held
    assert _post(client, "/api/night/stop").status_code == 409  # nothing running


def test_pages_and_reading_endpoints(plant_console):
    console, client = plant_console
    for page in ("/field", "/campaign", "/reports", "/heliostat/H02", "/commission/H14"):
        r = client.get(page)
        assert r.status_code == 200 and "<script" in r.text
    assert client.get("/static/console.js").status_code == 200
    plant = client.get("/api/plant").json()
    assert plant["token_required"] and [h["id"] for h in plant["heliostats"]] == ["H02", "H14"]
    # This fixture runs no background poller (Console.start): read the drive once, as the poller
    # would, so the test does not depend on an earlier test having moved H02.
    assert console.poll("H02") is not None
    h = client.get("/api/heliostats/H02").json()
    assert h["limits"]["az"][0] < h["limits"]["az"][1] and h["status"]["faults"] == []
    assert client.get("/api/heliostats/H99").status_code == 400
    names = [c["name"] for c in client.get("/api/reports").json()["campaigns"]]
    assert names[:2] == ["api-pause", "api-abort"] and all("/night-" in n for n in names[2:])
    r = client.get(f"/reports/campaign/{console.store.campaign_by_name('api-abort').id}/report.html")
    assert r.status_code == 200 and "api-abort" in r.text
    assert client.get("/reports/campaign/1/../../etc/passwd").status_code in (400, 404)
    nights = client.get("/api/reports").json()["nights"]
    assert [n["index"] for n in nights] == list(range(len(nights))) and nights[0]["kind"] == "calibration"
    r = client.get("/reports/night/0/report.html")
    assert r.status_code == 200 and nights[0]["name"] in r.text
    assert client.get(f"/reports/night/{len(nights)}/report.html").status_code == 400


def test_model_sigma_is_never_one_figure_over_two_units():
    from controller.calibration.records import ModelRecord
    from controller.console.views import model_json

    m = model_json(ModelRecord({}, {"az_offset_mrad": 0.4, "tilt_east_mrad": 0.9, "position_e_mm": 30.0,
                                    "el_stroke0_mm": None}, 0.1, 5))
    assert (m["sigma_max_mrad"], m["sigma_max_mm"]) == (0.9, 30.0)


def test_event_bus_delivers_across_threads():
    bus = EventBus()

    async def main():
        stream = bus.stream()
        assert (await stream.__anext__()).startswith("retry:")
        threading.Thread(target=bus.publish, args=("drive", {"heliostat": "H02", "az": 5})).start()
        frame = await asyncio.wait_for(stream.__anext__(), 5.0)
        bus.close()
        rest = [f async for f in stream]
        return frame, rest

    frame, rest = asyncio.run(main())
    assert frame.startswith("event: drive\ndata: ") and '"az": 5' in frame and rest == []
