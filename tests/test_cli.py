"""The ``heliocal`` entry point: --version, command discovery and the ``sun`` contract."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from controller import __version__
from controller.cli import main


def test_version_subprocess():
    res = subprocess.run([sys.executable, "-m", "controller.cli", "--version"], capture_output=True,
                         text=True, timeout=60, check=False)
    assert res.returncode == 0
    assert res.stdout.strip() == f"heliocal {__version__}"


def test_help_lists_commands(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "sun" in out and "demo" in out


def test_no_command_prints_help_and_exits_2(capsys):
    assert main([]) == 2
    assert "usage" in capsys.readouterr().out


SPA_ARGS = ["sun", "--time", "2003-10-17T12:30:30-07:00", "--lat", "39.742476", "--lon", "-105.1786",
            "--elevation", "1830.14", "--pressure", "820", "--temperature", "11", "--delta-t", "67"]


def test_sun_json_contract(capsys):
    assert main([*SPA_ARGS, "--json"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1
    data = json.loads(out[0])
    assert list(data) == ["zenith_deg", "azimuth_deg", "elevation_deg"]
    assert data["zenith_deg"] == pytest.approx(50.11162, abs=3e-4)
    assert data["azimuth_deg"] == pytest.approx(194.34024, abs=3e-4)
    assert data["elevation_deg"] == pytest.approx(90 - 50.11162, abs=3e-4)


def test_sun_readable_line(capsys):
    assert main(SPA_ARGS) == 0
    out = capsys.readouterr().out.strip()
    assert len(out.splitlines()) == 1 and "azimuth 194.3402" in out and "zenith 50.1116" in out


def test_sun_naive_time_needs_utc_flag(capsys):
    assert main([*SPA_ARGS[:2], "2003-10-17T19:30:30", *SPA_ARGS[3:], "--json"]) == 2
    assert "has no UTC offset" in json.loads(capsys.readouterr().out)["error"]
    assert main([*SPA_ARGS[:2], "2003-10-17T19:30:30", *SPA_ARGS[3:], "--utc", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["azimuth_deg"] == pytest.approx(194.34024, abs=3e-4)
    assert main([*SPA_ARGS[:2], "2003-10-17T19:30:30Z", *SPA_ARGS[3:], "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["azimuth_deg"] == pytest.approx(194.34024, abs=3e-4)


def test_sun_human_output_names_hemispheres(capsys):
    assert main(SPA_ARGS) == 0
    assert "39.742476°N 105.178600°W" in capsys.readouterr().out
    assert main(["sun", "--time", "now", "--lat", "-33", "--lon", "18", "--json"]) == 0
    assert 0 <= json.loads(capsys.readouterr().out)["azimuth_deg"] < 360


def test_sun_defaults_to_config_site(capsys):
    assert main(["sun", "--time", "2024-06-21T12:00:00Z", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    # Demo site 37°N, 2.4°W at 12:00 UTC on the solstice: the sun is near the meridian, south,
    # at about 90 − 37 + 23.44 = 76.4° elevation.
    assert data["elevation_deg"] == pytest.approx(76.4, abs=0.5)
    assert 160 < data["azimuth_deg"] < 200


@pytest.mark.parametrize("args, fragment", [
    (["--time", "yesterday", "--lat", "1", "--lon", "2"], "--time: 'yesterday' is not an ISO 8601 time"),
    (["--time", "2003-10-17", "--lat", "91", "--lon", "2"], "--lat: 91 is outside [-90, 90]"),
    (["--time", "2003-10-17", "--lat", "1", "--lon", "east"], "--lon: 'east' is not a number"),
    (["--time", "2003-10-17", "--lat", "1", "--lon", "2", "--pressure", "0"], "--pressure: 0 is outside"),
    (["--time", "2003-10-17", "--lat", "1", "--lon", "2", "--delta-t", "nan"], "--delta-t: nan is outside"),
    (["--time", "2003-10-17", "--lat", "1"], "--lat and --lon must be given together"),
    (["--time", "2003-10-17", "--lat", "1", "--lon", "2"], "--time: '2003-10-17' has no UTC offset"),
])
def test_sun_bad_input_exits_2(capsys, args, fragment):
    assert main(["sun", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and fragment in err
    assert main(["sun", *args, "--json"]) == 2
    data = json.loads(capsys.readouterr().out)
    assert data["ok"] is False and fragment in data["error"]
