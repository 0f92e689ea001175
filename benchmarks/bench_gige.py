"""GigE Vision pair capture rate: GigeCamera against ``arv-fake-gv-camera-0.8`` on loopback.

    .venv/bin/python benchmarks/bench_gige.py [--seconds 2]

LOW is the GigE Vision fake (GVCP/GVSP over 127.0.0.1), HIGH Aravis's in-process ``Fake_1``;
ROI 64x48 Mono8. Printed (one JSON object):

- ``pairs_per_s_free``: ``GigeCamera.capture()`` with both imagers free-running at 1 kHz
  (drain stale frames, wait for the next of each, copy, skew check);
- ``peer_raw_aravis_frames_per_s``: the peer, a bare Aravis pop/push loop on the GigE device
  alone in the same run and settings: what the device and transport deliver;
- ``ratio_pairs_to_peer``: the first over the second (1.0: pairing costs nothing);
- ``pairs_per_s_software``: software-triggered pairs, paced by the fakes (they serve a
  trigger at the next tick of a 25 Hz grid), so at most 25.
"""

from __future__ import annotations

import argparse
import fcntl
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from controller.config import Camera
from controller.devices.gige import GigeCamera
from controller.devices.gige_device import aravis, discovered_devices

FAKE_GV = "arv-fake-gv-camera-0.8"
W, H = 64, 48


def _config(device_id: str, trigger: str) -> Camera:
    return Camera.model_validate({
        "sensors": [{"name": "low", "exposure_s": 0.001}, {"name": "high", "exposure_s": 0.002}],
        "width_px": W, "height_px": H, "bit_depth": 8, "driver": "gige",
        "gige": {"low": device_id, "high": "Fake_1", "trigger": trigger, "frame_rate_hz": 1000,
                 "max_skew_ms": 1000, "buffers": 8}})


def _pairs_per_s(cam: GigeCamera, seconds: float) -> float:
    cam.capture()
    n, t0 = 0, time.perf_counter()
    while (elapsed := time.perf_counter() - t0) < seconds:
        cam.capture()
        n += 1
    return n / elapsed


def _raw_frames_per_s(device_id: str, seconds: float) -> float:
    arv = aravis()
    cam = arv.Camera.new(device_id)
    cam.set_region(0, 0, W, H)
    cam.set_pixel_format_from_string("Mono8")
    cam.clear_triggers()
    cam.set_frame_rate(1000)
    stream = cam.create_stream(None, None)
    for _ in range(8):
        stream.push_buffer(arv.Buffer.new_allocate(cam.get_payload()))
    cam.start_acquisition()
    n, t0 = 0, time.perf_counter()
    while (elapsed := time.perf_counter() - t0) < seconds:
        buf = stream.timeout_pop_buffer(1_000_000)
        if buf is not None:
            n += buf.get_status() == arv.BufferStatus.SUCCESS
            stream.push_buffer(buf)
    cam.stop_acquisition()
    return n / elapsed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=2.0, help="duration of each measurement")
    args = ap.parse_args()
    if shutil.which(FAKE_GV) is None:
        sys.exit(f"bench_gige: {FAKE_GV} not found (Debian package aravis-tools)")
    # One GigE Vision device can own 127.0.0.1:3956: share the tests' lock.
    with open(Path(tempfile.gettempdir()) / "heliocal-gvcp-3956.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        serial = f"HCB{os.getpid() % 100000}"
        device_id = f"Aravis-Fake-{serial}"
        proc = subprocess.Popen([FAKE_GV, "-i", "127.0.0.1", "-s", serial],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            deadline = time.monotonic() + 15
            while not any(d.startswith(device_id + " ") for d in discovered_devices()):
                if time.monotonic() > deadline or proc.poll() is not None:
                    sys.exit(f"bench_gige: {device_id} did not come up on 127.0.0.1")
            peer = _raw_frames_per_s(device_id, args.seconds)
            result = {}
            for trigger in ("free", "software"):
                cam = GigeCamera(_config(device_id, trigger))
                try:
                    result[trigger] = _pairs_per_s(cam, args.seconds)
                finally:
                    cam.close()
        finally:
            proc.kill()
            proc.wait()
    print(json.dumps({
        "pairs_per_s_free": round(result["free"], 1),
        "peer_raw_aravis_frames_per_s": round(peer, 1),
        "ratio_pairs_to_peer": round(result["free"] / peer, 3),
        "pairs_per_s_software": round(result["software"], 1),
        "roi": [W, H], "pixel_format": "Mono8", "seconds": args.seconds,
    }))


if __name__ == "__main__":
    main()
