"""Console request bodies are checked as the CLI checks its options (one piece of code,
controller.commands._id_lists), and every answer is JSON — Starlette's own 404 and 405 included.
Through a real HTTP client (urllib) against a console server process the test starts."""

from __future__ import annotations

import json
import urllib.error
import urllib.request

import pytest

from tests.conftest import scaled_s


def _call(url: str, method: str = "GET", body: bytes | None = None) -> tuple[int, dict]:
    req = urllib.request.Request(url, data=body, method=method,
                                 headers={"Content-Type": "application/json"} if body is not None else {})
    try:
        with urllib.request.urlopen(req, timeout=scaled_s(30)) as r:
            status, raw, kind = r.status, r.read(), r.headers.get("content-type", "")
    except urllib.error.HTTPError as e:
        status, raw, kind = e.code, e.read(), e.headers.get("content-type", "")
    assert kind.startswith("application/json"), (url, status, kind, raw[:200])
    return status, json.loads(raw)


BAD_BODIES = [  # (path, body, words the error must hold)
    ("/api/night/start", {"heliostats": ["H02", "H02"]}, "'H02' is given twice"),
    ("/api/campaign/start", {"heliostats": ["H08", "H08"]}, "'H08' is given twice"),
    ("/api/night/start", {"heliostats": "H02"}, "must be a list"),
    ("/api/night/start", {"heliostats": [2]}, "must be a list"),
    ("/api/night/start", {"heliostats": ["H99"]}, "H99"),
    ("/api/night/start", {"heliostats": [""]}, "not an id"),
    ("/api/night/start", {"heliostats": ["H02"], "strategy": "x"}, "unknown field 'strategy'"),
    ("/api/campaign/start", {"name": ["a"]}, "not a campaign name"),
    ("/api/campaign/start", {"name": "x\n"}, "not a campaign name"),
    ("/api/heliostats/H02/jog", {"az_steps": "10", "el_steps": 0}, "az_steps must be an integer"),
    ("/api/heliostats/H02/jog", {"az_steps": True, "el_steps": 0}, "az_steps must be an integer"),
    ("/api/heliostats/H02/jog", {"az_steps": 1, "el_steps": 0, "speed": 3}, "unknown field 'speed'"),
    ("/api/heliostats/H02/stop", {"now": True}, "unknown field 'now'"),
]


def test_bad_bodies_are_refused_as_the_cli_refuses_them(console_server):
    base = console_server.url
    for path, body, words in BAD_BODIES:
        status, out = _call(base + path, "POST", json.dumps(body).encode())
        assert status == 400 and out["ok"] is False and words in out["error"], (path, body, status, out)
    status, night = _call(base + "/api/night")
    assert status == 200 and not night["running"] and night["outcome"] is None  # nothing was started
    status, camp = _call(base + "/api/campaign")
    assert status == 200 and not camp.get("running")


@pytest.mark.parametrize("method,path,status", [
    ("GET", "/no/such/page", 404), ("GET", "/api/nothing", 404), ("POST", "/api/nothing", 404),
    ("GET", "/reports/campaign/x/", 404), ("POST", "/api/alarms/x/ack", 404),
    ("DELETE", "/api/plant", 405), ("PUT", "/api/heliostats", 405), ("GET", "/api/night/start", 405),
])
def test_every_answer_is_json(console_server, method, path, status):
    got, out = _call(console_server.url + path, method, b"{}" if method in ("POST", "PUT") else None)
    assert got == status and out["ok"] is False and out["error"], (method, path, got, out)
