"""``heliocal console`` on the command line: the bind rules and the token, end to end."""

from __future__ import annotations

import json
import subprocess
import sys
import urllib.error
import urllib.request

from tests.console.conftest import REPO, ConsoleProcess, small_config_file


def _console(*args):
    return subprocess.run([sys.executable, "-m", "controller.cli", "console", *args], cwd=REPO,
                          capture_output=True, text=True, timeout=60)


def test_non_loopback_bind_needs_a_token(tmp_path):
    db = tmp_path / "c.db"
    for host in ("0.0.0.0", "192.0.2.10", "::"):
        r = _console("--db", str(db), "--simulate", "--host", host)
        assert r.returncode == 2, r.stderr
        assert "--token" in r.stderr and host in r.stderr and "Traceback" not in r.stderr
    r = _console("--db", str(db), "--simulate", "--host", "0.0.0.0", "--token", "short")
    assert r.returncode == 2 and "at least 12 characters" in r.stderr
    r = _console("--db", str(db), "--simulate", "--token-file", str(tmp_path / "missing.txt"))
    assert r.returncode == 2 and "missing.txt" in r.stderr
    assert not db.exists()  # refused before anything was opened


def _post(url: str, token: str | None) -> int:
    headers = {"Content-Type": "application/json"}
    if token is not None:
        headers["X-Heliocal-Token"] = token
    body = json.dumps({"az_steps": 100, "el_steps": 0}).encode()
    req = urllib.request.Request(url, data=body, method="POST", headers=headers)
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            return r.status
    except urllib.error.HTTPError as exc:
        return exc.code


def test_token_file_enforced_over_http(tmp_path):
    token_file = tmp_path / "token"
    token_file.write_text("a-long-enough-console-token\n")
    cfg = small_config_file(tmp_path / "small.yaml")
    proc = ConsoleProcess(["--config", str(cfg), "--db", str(tmp_path / "c.db"), "--simulate", "--heliostats",
                           "H02", "--port", "0", "--token-file", str(token_file),
                           "--run-dir", str(tmp_path / "run")])
    try:
        assert "token required" in "".join(proc.stderr)

        def az() -> int:
            with urllib.request.urlopen(f"{proc.url}/api/heliostats/H02", timeout=10) as r:
                return json.loads(r.read())["status"]["az_steps"]

        start = az()
        assert _post(f"{proc.url}/api/heliostats/H02/jog", None) == 401
        assert _post(f"{proc.url}/api/heliostats/H02/jog", "a-long-enough-console-token-x") == 401
        assert az() == start
        assert _post(f"{proc.url}/api/heliostats/H02/jog", "a-long-enough-console-token") == 200
        assert az() == start + 100
    finally:
        rc = proc.stop()
    # Ctrl-C: the jogged heliostat is parked before the console exits.
    assert rc in (0, 130) and "H02 parked" in "".join(proc.stderr), "".join(proc.stderr)
