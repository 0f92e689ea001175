"""``heliocal lamps`` against the simulated plant's lamp panel: the plant's lamps (what its
cameras render with) are the truth the output is checked against."""

from __future__ import annotations

import contextlib
import io
import json
import signal
import subprocess
import sys
import time

import pytest
import yaml

from controller.cli import main
from simplant.plant import SimulatedPlant, load_config_data
from tests.calibration.conftest import REPO
from tests.conftest import scaled_s
from tests.devices.tcp_peers import NotAPanel


@pytest.fixture(scope="module")
def field(tmp_path_factory):
    """The running plant and its rewritten config file (short confirmation timeout)."""
    run = tmp_path_factory.mktemp("lamps-cli")
    plant = SimulatedPlant(load_config_data(REPO / "configs" / "demo.yaml"), run / "plant",
                           heliostat_ids=["H01"], seed=6)
    plant.start()
    data = dict(plant.data, lamps={**plant.data["lamps"], "confirm_timeout_s": scaled_s(0.5)})
    path = run / "plant.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    yield plant, path
    plant.stop()


def _lamps(capsys, path, *args: str) -> tuple[int, str, str]:
    code = main(["lamps", "--config", str(path), *args])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_status_on_off_and_all_off(field, capsys):
    plant, path = field
    plant.lamp_panel.no_confirm.clear()
    code, out, _ = _lamps(capsys, path, "all-off", "--json")
    assert code == 0 and plant.lit is None
    assert not any(s["lit"] or s["commanded"] for s in json.loads(out)["lamps"])
    code, out, _ = _lamps(capsys, path, "on", "lamp-west", "--json")
    doc = json.loads(out)
    assert code == 0 and plant.lit == "lamp-west"
    assert doc["ok"] and doc["action"] == "on" and doc["channel"] == "lamp-west"
    assert doc["panel"] == f"lamp panel modbus-tcp 127.0.0.1:{plant.lamp_panel.port} unit 1"
    lit = {s["channel"]: (s["commanded"], s["lit"]) for s in doc["lamps"]}
    assert lit["lamp-west"] == (True, True) and lit["lamp-east"] == (False, False)
    assert list(lit) == list(yaml.safe_load(path.read_text())["lamps"]["channels"])
    # on switches only that lamp: lamp-west stays lit beside lamp-east
    assert _lamps(capsys, path, "on", "lamp-east")[0] == 0
    assert plant.lamp_lit("lamp-west") and plant.lamp_lit("lamp-east")
    code, out, _ = _lamps(capsys, path, "off", "lamp-west")
    assert code == 0 and not plant.lamp_lit("lamp-west") and plant.lamp_lit("lamp-east")
    code, out, _ = _lamps(capsys, path)  # status is the default
    lines = {line.split()[0]: line.split()[1] for line in out.splitlines()}
    assert code == 0 and lines["lamp-east"] == "lit" and lines["lamp-west"] == "dark"
    assert _lamps(capsys, path, "all-off")[0] == 0 and plant.lit is None


def test_a_lamp_that_does_not_confirm_exits_1_naming_it(field, capsys):
    plant, path = field
    plant.lamp_panel.no_confirm.add("lamp-far-east")
    try:
        code, out, err = _lamps(capsys, path, "on", "lamp-far-east")
        assert code == 1 and err.strip() == (
            f"heliocal lamps: error: lamp lamp-far-east did not confirm lit within {scaled_s(0.5):g} s")
        code, out, _ = _lamps(capsys, path, "on", "lamp-far-east", "--json")
        assert code == 1 and json.loads(out) == {
            "ok": False, "error": f"lamp lamp-far-east did not confirm lit within {scaled_s(0.5):g} s"}
    finally:
        plant.lamp_panel.no_confirm.clear()
        assert _lamps(capsys, path, "all-off")[0] == 0


@pytest.mark.parametrize("args, said", [
    (("on", "lamp-north"), "no lamp channel 'lamp-north' in lamps.channels (known: lamp, lamp-west"),
    (("on",), "lamps on: name the LAMP to switch"),
    (("status", "lamp"), "lamps status: takes no LAMP"),
])
def test_bad_input_exits_2_before_anything_is_switched(field, capsys, args, said):
    plant, path = field
    before = len(plant.lamp_panel.writes)
    code, _, err = _lamps(capsys, path, *args)
    assert code == 2 and said in err and len(err.strip().splitlines()) == 1
    assert len(plant.lamp_panel.writes) == before


def test_a_config_without_a_lamp_panel_exits_2(capsys):
    code, _, err = _lamps(capsys, REPO / "configs" / "demo.yaml", "status")
    assert code == 2 and "demo.yaml: no lamps: section" in err


def test_an_unknown_action_is_a_usage_error(field, capsys):
    _, path = field
    assert main(["lamps", "--config", str(path), "blink", "lamp"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == ["heliocal lamps: error: argument action: invalid choice: 'blink' (choose from 'status', "
                   "'on', 'off', 'all-off') (see heliocal lamps --help)"]


@pytest.mark.parametrize("kind", ["echo", "fc05", "garbage"])
def test_lamps_against_a_peer_that_is_not_a_panel_exit_1_and_report_nothing_lit(field, capsys, kind):
    _, path = field
    data = yaml.safe_load(path.read_text())
    with NotAPanel(kind) as peer:
        data["lamps"].update(port=peer.port, timeout_s=scaled_s(0.2))
        bad = path.with_name(f"not-a-panel-{kind}.yaml")
        bad.write_text(yaml.safe_dump(data, sort_keys=False))
        for args in (("status",), ("status", "--json"), ("on", "lamp-west")):
            code, out, err = _lamps(capsys, bad, *args)
            said = json.loads(out)["error"] if "--json" in args else err.strip()
            assert code == 1 and said.count("\n") == 0 and f"127.0.0.1:{peer.port}" in said
            assert "lit" not in out and "ok\": true" not in out


@pytest.mark.parametrize("action, sig", [("on", signal.SIGINT), ("on", signal.SIGTERM),
                                         ("all-off", signal.SIGINT)])
def test_interrupted_while_waiting_for_the_confirmation_the_lamp_is_left_off(field, action, sig):
    """A real ``heliocal lamps`` process, signalled once its coil is written (the lamp never
    confirms lit, so it is still waiting): the coil goes off again, confirmed, exit 130."""
    plant, path = field
    data = yaml.safe_load(path.read_text())
    data["lamps"]["confirm_timeout_s"] = scaled_s(60)
    slow = path.with_name(f"slow-confirm-{action}-{sig.name}.yaml")
    slow.write_text(yaml.safe_dump(data, sort_keys=False))
    panel = plant.lamp_panel
    lamp = "lamp-far-east"
    try:
        if action == "on":
            panel.no_confirm.add(lamp)  # its coil is written, it stays dark: the command waits
        else:  # all-off waits on a lamp that stays lit after its coil went off
            assert _lamps_quiet(path, "on", lamp) == 0
            panel.stuck_lit.add(lamp)
        before = len(panel.writes)
        argv = ["lamps", "--config", str(slow), action, *([lamp] if action == "on" else [])]
        proc = subprocess.Popen([sys.executable, "-m", "controller.cli", *argv], cwd=REPO, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        awaited = (lamp, action == "on")
        deadline = time.monotonic() + scaled_s(20)
        while awaited not in panel.writes[before:] and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.01)
        assert awaited in panel.writes[before:], proc.communicate(timeout=scaled_s(20))
        if action == "all-off":
            panel.stuck_lit.discard(lamp)  # it goes dark now; the command still waits for its next poll
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=scaled_s(20))
        what = f"lamp {lamp}" if action == "on" else "every lamp"
        assert proc.returncode == 130 and err.strip().splitlines() == [
            f"heliocal lamps: interrupted; {what} switched off and confirmed dark"]
        assert [w for w in panel.writes if w[0] == lamp][-1] == (lamp, False)
        assert not panel.coils[panel.channels[lamp]] and not plant.lamp_lit(lamp)
        if action == "all-off":
            assert not any(panel.coils) and plant.lit is None
    finally:
        panel.no_confirm.clear()
        panel.stuck_lit.clear()
        assert _lamps_quiet(path, "all-off") == 0


def _lamps_quiet(path, *args: str) -> int:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return main(["lamps", "--config", str(path), *args])
