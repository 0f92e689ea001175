"""The coarse correction of a confident match in the loop: when it applies, what it moves,
and that its step goes through the same limits as every move."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.calibration.coarse import coarse_applies, correction_step, predicted_offset_enu
from controller.calibration.observations import Match, Observation

from .conftest import AIM, HELIOSTAT, A


class _Pointing:
    """Records what it is asked; the step is the offset itself (m -> 'steps' x 1000)."""

    heliostat_pos = np.array([0.0, 0.0, 0.0])
    aim_point = np.array([0.0, 100.0, 0.0])  # due north, level, 100 m

    def __init__(self):
        self.asked = []

    def fine_correction(self, az, el, offset_enu):
        from controller.calibration.observations import Step
        self.asked.append(np.asarray(offset_enu, float))
        return Step(0.0, 0.0, int(round(-1000 * offset_enu[0])), int(round(-1000 * offset_enu[2])))

    def coarse_correction(self, az, el, daz_deg, del_deg):
        raise AssertionError("no entry correction in these matches")


def test_predicted_offset_is_range_times_the_beam_angle():
    p = _Pointing()
    # Azimuth clockwise from north: +0.1 deg turns a north-going beam towards east (+x).
    east = predicted_offset_enu(p, (0.1, 0.0))
    assert east[0] == pytest.approx(100 * math.radians(0.1), rel=1e-4) and abs(east[2]) < 1e-6
    up = predicted_offset_enu(p, (0.0, -0.2))
    assert up[2] == pytest.approx(-100 * math.radians(0.2), rel=1e-4) and abs(up[0]) < 1e-6


OBS = Observation((0.0, 0.0), (0.3, 100.0, -0.2), np.ones(7), 1.0)
SURE = Match("wind-load", 0.1, "gravity-sag", 2.0, coarse_correction_deg=(-0.1, 0.05), confidence=0.8)


def test_confident_match_gives_the_coarse_step_from_its_estimate():
    p = _Pointing()
    kind, step = correction_step(p, 0, 0, OBS, SURE, first=True, min_confidence=0.5)
    assert kind == "coarse"
    np.testing.assert_allclose(p.asked[0], predicted_offset_enu(p, (0.1, -0.05)))
    assert step.daz_steps == int(round(-1000 * p.asked[0][0]))


@pytest.mark.parametrize("match, first, threshold, obs", [
    (SURE, True, None, OBS),  # disabled in the config
    (SURE, True, 0.9, OBS),  # not confident enough
    (SURE, False, 0.5, OBS),  # only on the first measurement
    (Match("wind-load", 0.1, unknown=True, coarse_correction_deg=(-0.1, 0.05), confidence=0.8),
     True, 0.5, OBS),
    (SURE, True, 0.5, Observation((0.0, 0.0), (0.3, 100.0, -0.2), np.ones(7), 1.0, ("left",))),  # clipped
    (None, True, 0.5, OBS),  # no library
])
def test_otherwise_the_centroid_gives_the_fine_step(match, first, threshold, obs):
    p = _Pointing()
    kind, _ = correction_step(p, 0, 0, obs, match, first=first, min_confidence=threshold)
    assert kind == "fine"
    np.testing.assert_allclose(p.asked[0], np.asarray(obs.centroid_enu) - p.aim_point)
    assert not coarse_applies(match, threshold) or not first or obs.clipped


def _true_error_deg(offset_m: np.ndarray) -> tuple[float, float]:
    """Beam error (Δaz, Δel) in degrees that moves the spot by ``offset_m`` (east, up) at AIM."""
    from controller.geometry.vectors import vector_to_azel

    (a0, e0), (a1, e1) = (vector_to_azel(p - HELIOSTAT) for p in (AIM, AIM + [offset_m[0], 0.0, offset_m[1]]))
    return float(a1 - a0), float(e1 - e0)


def test_machine_applies_a_confident_coarse_correction_once_then_refines(make_cycle):
    cyc, plant, _ = make_cycle()
    err = _true_error_deg(A @ plant.hidden_steps)  # the beam's offset at the aim, from the hidden error
    cyc.ctx.match = lambda hu: Match("wind-load", 0.1, "gravity-sag", 2.0,
                                     coarse_correction_deg=(-err[0], -err[1]), confidence=0.9)
    cyc.ctx.coarse_confidence = 0.5
    rec = cyc.run()
    kinds = [c.kind for c in rec.corrections]
    assert kinds[0] == "coarse" and set(kinds[1:]) <= {"fine"}
    # The estimate is the true error here, so the coarse move alone nearly removes it.
    assert plant.true_errors[1] < 0.2 * plant.true_errors[0]
    assert rec.status == "calibrated"


def test_a_wild_coarse_correction_is_clamped_to_the_drive_limits(make_cycle):
    cyc, _, drive = make_cycle(max_iterations=2)
    cyc.ctx.match = lambda hu: Match("wind-load", 0.1, "gravity-sag", 2.0,
                                     coarse_correction_deg=(-40.0, 30.0), confidence=0.99)
    cyc.ctx.coarse_confidence = 0.5
    seen = []
    real_move = drive.move_and_wait

    def move(az, el, **kw):
        seen.append((az, el))
        return real_move(az, el, **kw)

    drive.move_and_wait = move
    rec = cyc.run()
    assert rec.corrections[0].kind == "coarse"
    lim = drive.limits
    assert all(lim.az.min_steps <= a <= lim.az.max_steps and lim.el.min_steps <= e <= lim.el.max_steps
               for a, e in seen)


@pytest.mark.parametrize("value, rule", [(1.5, "less than or equal to 1"), ("high", "valid number")])
def test_bad_coarse_correction_threshold_is_refused_naming_the_key(tmp_path, capsys, value, rule):
    import yaml

    from controller.cli import main

    from .conftest import REPO

    data = yaml.safe_load((REPO / "configs" / "demo.yaml").read_text(encoding="utf-8"))
    data["calibration"]["coarse_correction"] = value
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data), encoding="utf-8")
    assert main(["demo", "--config", str(bad)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and len(err.strip().splitlines()) == 1
    assert f"{bad}: calibration.coarse_correction: " in err and rule in err


def test_demo_coarse_summary_counts_runs_with_a_coarse_first_move():
    from types import SimpleNamespace as NS

    from controller.calibration.records import CorrectionRecord
    from controller.commands.demo import coarse_summary

    runs = [NS(id=1, iterations=3), NS(id=2, iterations=1), NS(id=3, iterations=2)]
    moves = {1: [CorrectionRecord(1, "coarse", 0, 0, 0, 0), CorrectionRecord(2, "fine", 0, 0, 0, 0)],
             2: [], 3: [CorrectionRecord(1, "fine", 0, 0, 0, 0)]}
    store = NS(runs=lambda cid: runs, corrections=lambda rid: moves[rid])
    s = coarse_summary(store, 7, 0.5)
    assert (s["threshold"], s["applied"], s["iterations_mean"]) == (0.5, 1, 2.0)
    assert (s["iterations_mean_runs_with_coarse"], s["iterations_mean_runs_without_coarse"]) == (3.0, 1.5)
