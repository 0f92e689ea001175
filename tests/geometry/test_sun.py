"""Solar position against published numbers: the NREL SPA worked example and a PAINT record."""

from __future__ import annotations

import json
import subprocess
import sys
from datetime import UTC, datetime, timedelta, timezone

import numpy as np
import pytest

from controller.geometry.frames import paint_azimuth_to_north
from controller.geometry.sun import solar_position

# Reda & Andreas (2004), Table A5.1: Golden, CO, 2003-10-17 12:30:30 local (UTC-7).
SPA_TIME = datetime(2003, 10, 17, 12, 30, 30, tzinfo=timezone(timedelta(hours=-7)))
SPA_SITE = dict(latitude_deg=39.742476, longitude_deg=-105.1786, elevation_m=1830.14,
                pressure_mbar=820.0, temperature_c=11.0, delta_t_s=67.0)
SPA_ZENITH, SPA_AZIMUTH = 50.11162, 194.34024
SPA_TOL = 0.0003  # degrees: the SPA's stated uncertainty


def test_spa_worked_example():
    pos = solar_position(SPA_TIME, **SPA_SITE)
    assert pos.zenith_deg == pytest.approx(SPA_ZENITH, abs=SPA_TOL)
    assert pos.azimuth_deg == pytest.approx(SPA_AZIMUTH, abs=SPA_TOL)
    assert pos.elevation_deg == pytest.approx(90.0 - SPA_ZENITH, abs=SPA_TOL)


def test_naive_time_is_utc():
    aware = solar_position(SPA_TIME, **SPA_SITE)
    naive = solar_position(datetime(2003, 10, 17, 19, 30, 30), **SPA_SITE)
    assert naive.zenith_deg == pytest.approx(aware.zenith_deg, abs=1e-9)
    assert naive.azimuth_deg == pytest.approx(aware.azimuth_deg, abs=1e-9)


def test_sequence_of_times_gives_arrays():
    times = [SPA_TIME, SPA_TIME + timedelta(hours=1)]
    pos = solar_position(times, **SPA_SITE)
    assert pos.zenith_deg.shape == (2,)
    assert pos.zenith_deg[0] == pytest.approx(SPA_ZENITH, abs=SPA_TOL)
    # An hour after local noon in autumn the sun is lower and further west (azimuth grows).
    assert pos.zenith_deg[1] > pos.zenith_deg[0]
    assert pos.azimuth_deg[1] > pos.azimuth_deg[0]


def test_refraction_lifts_the_sun():
    """A thinner atmosphere bends less: near-vacuum pressure gives a (slightly) larger zenith."""
    dense = solar_position(SPA_TIME, **{**SPA_SITE, "pressure_mbar": 1013.25})
    thin = solar_position(SPA_TIME, **{**SPA_SITE, "pressure_mbar": 1.0})
    # SPA Eq. (42) by hand, e0 = 39.872° (true elevation), P = 1013.25 mbar, T = 11 °C:
    # (1013.25/1010)(283/284) · 1.02 / (60 tan(39.872° + 10.3/(39.872 + 5.11))) = 0.02018°;
    # at 1 mbar it is 0.00002°.
    assert thin.zenith_deg - dense.zenith_deg == pytest.approx(0.02018 - 0.00002, abs=0.0002)


def test_estimated_delta_t_is_close_to_67s_in_2003():
    pos = solar_position(SPA_TIME, **{**SPA_SITE, "delta_t_s": None})
    # ΔT in 2003 was 64.5 s; 2.5 s of time is ~0.01° of hour angle at most.
    assert pos.azimuth_deg == pytest.approx(SPA_AZIMUTH, abs=0.01)


def test_paint_record_sun_position(origin):
    """README check: image stamped 2022-08-07 16:22:57 UTC at Jülich -> elevation 24.740°,
    azimuth 265.60° (record: 24.739° and −85.60° from south)."""
    lat, lon, alt = origin
    pos = solar_position(datetime(2022, 8, 7, 16, 22, 57, tzinfo=UTC), lat, lon, alt)
    assert pos.elevation_deg == pytest.approx(24.740, abs=0.001)
    assert pos.azimuth_deg == pytest.approx(265.60, abs=0.005)
    assert pos.elevation_deg == pytest.approx(24.739, abs=0.002)
    assert pos.azimuth_deg == pytest.approx(float(paint_azimuth_to_north(-85.60)), abs=0.005)


def test_cli_spa_worked_example():
    out = subprocess.run(
        [sys.executable, "-m", "controller.cli", "sun", "--time", "2003-10-17T12:30:30-07:00",
         "--lat", "39.742476", "--lon", "-105.1786", "--elevation", "1830.14", "--pressure", "820",
         "--temperature", "11", "--delta-t", "67", "--json"],
        capture_output=True, text=True, timeout=60, check=False)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.strip().splitlines()
    assert len(lines) == 1
    data = json.loads(lines[0])
    assert set(data) == {"zenith_deg", "azimuth_deg", "elevation_deg"}
    assert data["zenith_deg"] == pytest.approx(SPA_ZENITH, abs=SPA_TOL)
    assert data["azimuth_deg"] == pytest.approx(SPA_AZIMUTH, abs=SPA_TOL)
    assert data["elevation_deg"] == pytest.approx(90.0 - data["zenith_deg"], abs=1e-9)
    assert np.isfinite(list(data.values())).all()
