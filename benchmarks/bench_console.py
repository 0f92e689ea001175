"""Console live-update latency: a drive status change on the simulated plant → the SSE event at
a client, against plain status polling in the same run.

Starts the simulated plant (3 heliostats, serial and Modbus TCP) and the console's app on
uvicorn (127.0.0.1, ephemeral port), connects an SSE client to ``/api/events`` and, per trial,
changes H02's drive target on the plant side (the firmware's controller, as a local operator
panel would: nothing goes through the console) at a random phase, then times until

* ``sse``: the first ``drive`` event showing the new target reaches the SSE client;
* ``http_poll`` (the named peer): a client polling ``GET /api/heliostats`` every
  ``--poll-ms`` (default the console's own status period) sees it — what a page without
  server-sent events would do;
* ``drive_poll``: a client polling the drive itself over its link back to back sees it (the
  floor: one status round trip).

Prints one JSON object: p50/p95 per path (seconds), the ratios sse / http_poll and
sse / drive_poll at p50, and whether sse p95 ≤ 0.5 s.

Usage: .venv/bin/python benchmarks/bench_console.py [--trials N] [--poll-ms MS]
"""

from __future__ import annotations

import argparse
import http.client
import json
import random
import socket
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import uvicorn  # noqa: E402

from controller.commands.simulated import plant_field  # noqa: E402
from controller.console.app import create_app  # noqa: E402
from controller.console.backend import STATUS_POLL_S, Console, PlantHooks  # noqa: E402
from controller.devices.drive import DriveLimits  # noqa: E402
from controller.devices.factory import LinkPool  # noqa: E402
from controller.storage.db import CampaignStore  # noqa: E402
from simplant.plant import SimulatedPlant, load_config_data  # noqa: E402
from simplant.settings import SimulationSettings  # noqa: E402

LIMIT_S = 0.5
HID = "H02"


class Watch:
    """When each observer first saw a target: ``seen[name][target] = time.monotonic()``."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.seen: dict[str, dict[int, float]] = {"sse": {}, "http_poll": {}, "drive_poll": {}}
        self.stop = threading.Event()

    def saw(self, name: str, target: int) -> None:
        t = time.monotonic()
        with self.lock:
            self.seen[name].setdefault(target, t)


def sse_client(port: int, w: Watch, ready: threading.Event) -> None:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    conn.request("GET", "/api/events")
    resp = conn.getresponse()
    ready.set()
    event = None
    while not w.stop.is_set():
        line = resp.fp.readline().decode()
        if not line:
            return
        if line.startswith("event: "):
            event = line[7:].strip()
        elif line.startswith("data: ") and event == "drive":
            d = json.loads(line[6:])
            if d["heliostat"] == HID and d["status"]:
                w.saw("sse", d["status"]["az_target"])


def http_poller(port: int, w: Watch, period_s: float) -> None:
    while not w.stop.is_set():
        t0 = time.monotonic()
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/heliostats", timeout=10) as r:
            rows = json.loads(r.read())["heliostats"]
        st = next(h for h in rows if h["id"] == HID)["status"]
        if st:
            w.saw("http_poll", st["az_target"])
        w.stop.wait(max(0.0, period_s - (time.monotonic() - t0)))


def drive_poller(drive, w: Watch) -> None:
    while not w.stop.is_set():
        w.saw("drive_poll", drive.status().az_target)


def stats(values: list[float]) -> dict:
    a = np.asarray(values)
    return {"p50_s": round(float(np.percentile(a, 50)), 4), "p95_s": round(float(np.percentile(a, 95)), 4),
            "max_s": round(float(a.max()), 4), "n": len(values)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=40, help="status changes to time (default 40)")
    ap.add_argument("--poll-ms", type=float, default=STATUS_POLL_S * 1000,
                    help=f"period of the HTTP polling peer, ms (default {STATUS_POLL_S * 1000:g})")
    args = ap.parse_args()
    cfg_path = ROOT / "configs" / "demo.yaml"
    ids = ["H02", "H08", "H14"]
    rng = random.Random(0)
    with tempfile.TemporaryDirectory() as tmp, \
            SimulatedPlant(load_config_data(cfg_path), Path(tmp) / "run", heliostat_ids=ids,
                           settings=SimulationSettings(), source=str(cfg_path)) as plant:
        plant.start()
        with LinkPool(timeout_s=0.5, retries=2) as pool, CampaignStore(Path(tmp) / "c.db") as store:
            console = Console(plant_field(plant, cfg_path, store, pool), heliostat_ids=ids,
                              hooks=PlantHooks(label="simulated plant"), work_dir=tmp)
            app = create_app(console)
            console.start()
            sock = socket.socket()
            sock.bind(("127.0.0.1", 0))
            port = sock.getsockname()[1]
            server = uvicorn.Server(uvicorn.Config(app, log_level="warning", lifespan="off",
                                                   timeout_graceful_shutdown=1))
            threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True).start()
            while not server.started:
                time.sleep(0.01)
            w = Watch()
            ready = threading.Event()
            h = plant.config.heliostat(HID)
            peer_drive = pool.drive(h.link, DriveLimits.from_axes(h.axes))
            threads = [threading.Thread(target=sse_client, args=(port, w, ready), daemon=True),
                       threading.Thread(target=http_poller, args=(port, w, args.poll_ms / 1000), daemon=True),
                       threading.Thread(target=drive_poller, args=(peer_drive, w), daemon=True)]
            for t in threads:
                t.start()
            ready.wait(10)
            time.sleep(0.5)
            ctl = plant.hidden[HID].controller
            az0 = ctl.status()["az_steps"]
            lat: dict[str, list[float]] = {k: [] for k in w.seen}
            for i in range(args.trials):
                time.sleep(rng.uniform(0.0, 0.2))  # a random phase against every poll period
                target = az0 + 200 * (i + 1)
                t0 = time.monotonic()
                ctl.move_abs(target, ctl.status()["el_target"])
                deadline = t0 + 5.0
                while time.monotonic() < deadline:
                    with w.lock:
                        if all(target in s for s in w.seen.values()):
                            break
                    time.sleep(0.002)
                with w.lock:
                    for k, s in w.seen.items():
                        if target in s:
                            lat[k].append(s[target] - t0)
            w.stop.set()
            server.should_exit = True
            console.bus.close()
            console.close()
    out = {k: stats(v) for k, v in lat.items()}
    out["status_period_s"] = STATUS_POLL_S
    out["http_poll_period_s"] = args.poll_ms / 1000
    out["sse_over_http_poll_p50"] = round(out["sse"]["p50_s"] / out["http_poll"]["p50_s"], 3)
    out["sse_over_drive_poll_p50"] = round(out["sse"]["p50_s"] / out["drive_poll"]["p50_s"], 3)
    out["sse_p95_within_limit"] = out["sse"]["p95_s"] <= LIMIT_S
    out["limit_s"] = LIMIT_S
    print(json.dumps(out))
    return 0 if out["sse_p95_within_limit"] and out["sse"]["n"] == args.trials else 1


if __name__ == "__main__":
    raise SystemExit(main())
