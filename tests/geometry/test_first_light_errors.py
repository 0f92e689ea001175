"""The simulated first-light field (simplant.truth.FIRST_LIGHT, ``heliocal demo --uncalibrated
real``) is the real field's: each heliostat of tests/data/real/paint-field at its first record,
its measured mirror normal (the sun's direction and the UTIS focal spot from its surveyed
position) against the nominal one (its properties file's kinematics at the record's motor steps),
as (azimuth error × cos elevation, elevation error) — computed here again from the files."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from controller.geometry.aiming import aim_normal, angle_mrad
from controller.geometry.paint_io import read_paint_set
from controller.geometry.vectors import vector_to_azel
from simplant.truth import FIRST_LIGHT, FIRST_LIGHT_NORMAL_MRAD, whole_mirror_turn

FIELD = Path(__file__).resolve().parents[1] / "data" / "real" / "paint-field"


def first_record_errors() -> list[tuple[float, float, float]]:
    """(azimuth error × cos el, elevation error, angle) mrad of each heliostat's first record."""
    out = []
    for folder in sorted(p for p in FIELD.iterdir() if p.is_dir()):
        h = folder.name
        first = min((folder / "calibration").glob("*.json"), key=lambda p: int(p.name.split("_")[0]))
        s = read_paint_set([str(first)], folder / f"{h}_properties.json", FIELD / "tower-measurements.json")
        smp = s.records[0].sample
        nominal = s.kinematics.normal(smp.az_steps, smp.el_steps)
        measured = aim_normal(smp.source_dir, s.kinematics.mirror_center(smp.az_steps, smp.el_steps),
                              smp.spot_enu)
        (a0, e0), (a1, e1) = vector_to_azel(nominal), vector_to_azel(measured)
        d_az = math.radians((a1 - a0 + 180.0) % 360.0 - 180.0) * 1e3 * math.cos(math.radians(e0))
        out.append((d_az, math.radians(e1 - e0) * 1e3, float(angle_mrad(nominal, measured))))
    return out


def test_the_first_light_sample_is_the_real_fields_first_records():
    errors = first_record_errors()
    assert len(errors) == len(FIRST_LIGHT_NORMAL_MRAD) == 16
    assert np.allclose([e[:2] for e in errors], FIRST_LIGHT_NORMAL_MRAD, atol=0.051)
    angles = np.array([e[2] for e in errors])
    assert np.median(angles) == pytest.approx(34.8, abs=0.1)  # the docs' figures
    assert np.percentile(angles, [25, 75]) == pytest.approx([19.5, 41.9], abs=0.1)


@pytest.mark.parametrize("facing", [(0.3, -0.7, 0.6), (0.0, -0.9, 0.2), (-0.5, -0.5, 0.7)])
def test_a_drawn_error_turns_the_facing_normal_as_measured(facing):
    f = np.asarray(facing) / np.linalg.norm(facing)
    spread = replace(FIRST_LIGHT, normal_error_mrad=((30.0, -10.0),), outlier=(0.0, 0.0))
    n = whole_mirror_turn(np.random.default_rng(1), spread, f) @ f
    (a0, e0), (a1, e1) = vector_to_azel(f), vector_to_azel(n)
    assert math.radians(a1 - a0) * 1e3 * math.cos(math.radians(e0)) == pytest.approx(30.0, abs=0.3)
    assert math.radians(e1 - e0) * 1e3 == pytest.approx(-10.0, abs=0.3)
    outlier = replace(spread, outlier=(1000.0, 1.0))  # always the outlier: 1 rad, any direction
    m = whole_mirror_turn(np.random.default_rng(1), outlier, f) @ f
    assert float(angle_mrad(f, m)) == pytest.approx(1000.0, rel=1e-6)
