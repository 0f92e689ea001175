"""The coarse correction in the loop: when it applies (a clipped spot with a confident centre
estimate; a library entry's stored correction), what it moves, that a library match's
interpolated estimate does not replace the centroid, and that every step goes through the same
limits as every move."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from controller.calibration.cycle.coarse import clipped_applies, correction_step
from controller.calibration.cycle.observations import Observation, Step
from controller.calibration.records import CorrectionRecord, MeasurementRecord, RunRecord
from controller.config import load_config
from controller.recognition.library import Match


class _Pointing:
    """Records what it is asked; the step is the offset itself (m -> 'steps' x 1000)."""

    heliostat_pos = np.array([0.0, 0.0, 0.0])
    aim_point = np.array([0.0, 100.0, 0.0])  # due north, level, 100 m

    def __init__(self):
        self.asked = []

    def fine_correction(self, az, el, offset_enu):
        from controller.calibration.cycle.observations import Step
        self.asked.append(np.asarray(offset_enu, float))
        return Step(0.0, 0.0, int(round(-1000 * offset_enu[0])), int(round(-1000 * offset_enu[2])))

    def coarse_correction(self, az, el, daz_deg, del_deg):
        raise AssertionError("no entry correction in these matches")


OBS = Observation((0.0, 0.0), (0.3, 100.0, -0.2), np.ones(7), 1.0)
SURE = Match("wind-load", 0.1, "gravity-sag", 2.0, coarse_correction_deg=(-0.1, 0.05), confidence=0.8)
CENTRE = (3.9, 100.0, -0.2)  # where the clipped spot's centre lies (beyond the visible centroid)
CLIPPED = Observation((1020.0, 300.0), (3.5, 100.0, -0.2), np.ones(7), 1.0, ("right",), CENTRE, 0.5)


def test_a_confident_clipped_centre_gives_the_coarse_step():
    p = _Pointing()
    kind, step = correction_step(p, 0, 0, CLIPPED, None, first=True, min_confidence=0.5)
    assert kind == "coarse"
    np.testing.assert_allclose(p.asked[0], np.asarray(CENTRE) - p.aim_point)
    assert step.daz_steps == int(round(-1000 * p.asked[0][0]))
    # On any clipped look, not only the first (a clipped look is not a measurement).
    assert correction_step(_Pointing(), 0, 0, CLIPPED, SURE, first=False, min_confidence=0.5)[0] == "coarse"


def _clipped(centre, conf) -> Observation:
    return Observation((1020.0, 300.0), (3.5, 100.0, -0.2), np.ones(7), 1.0, ("right",), centre, conf)


@pytest.mark.parametrize("match, first, threshold, obs", [
    (SURE, True, 0.5, OBS),  # a confident match on a spot in full view: the centroid measures it all
    (SURE, True, None, CLIPPED),  # disabled in the config
    (None, True, 0.6, CLIPPED),  # the centre's confidence is below the threshold
    (None, True, 0.5, _clipped(None, 0.0)),  # no centre estimate
    (None, True, 0.2, _clipped((float("nan"), 100.0, 0.0), 0.5)),  # not a number: never moved on
    (None, True, 0.5, OBS),  # no library, not clipped
])
def test_otherwise_the_centroid_gives_the_fine_step(match, first, threshold, obs):
    p = _Pointing()
    kind, _ = correction_step(p, 0, 0, obs, match, first=first, min_confidence=threshold)
    assert kind == "fine"
    np.testing.assert_allclose(p.asked[0], np.asarray(obs.centroid_enu) - p.aim_point)
    assert not clipped_applies(obs, threshold)


def test_a_confident_match_does_not_replace_the_centroid_in_the_machine(make_cycle):
    cyc, plant, _ = make_cycle()
    cyc.ctx.match = lambda hu: Match("wind-load", 0.1, "gravity-sag", 2.0,
                                     coarse_correction_deg=(-0.3, 0.2), confidence=0.95)
    cyc.ctx.coarse_confidence = 0.5
    rec = cyc.run()
    assert [c.kind for c in rec.corrections] == ["fine"] * len(rec.corrections)
    assert rec.status == "calibrated"


def test_a_wild_coarse_correction_is_clamped_to_the_drive_limits(make_cycle):
    cyc, _, drive = make_cycle(max_iterations=2)
    looks = []

    def analyze(frame):  # the first look is clipped with a (wrong) centre a kilometre away
        looks.append(frame)
        if len(looks) == 1:
            return Observation((0.0, 0.0), (0.0, 0.0, 30.0), np.ones(7), 1.0, ("left",),
                               (1000.0, 0.0, 30.0), 1.0)
        d = frame.metadata["offset"]
        return Observation((0.0, 0.0), (float(d[0]), 0.0, 30.0 + float(d[1])), np.ones(7), 1.0)

    cyc.ctx.analyze = analyze
    cyc.ctx.coarse_confidence = 0.5
    seen = []
    real_move = drive.move_and_wait

    def move(az, el, **kw):
        seen.append((az, el))
        return real_move(az, el, **kw)

    drive.move_and_wait = move
    rec = cyc.run()
    assert rec.corrections[0].kind == "coarse" and rec.corrections[0].iteration == 0
    lim = drive.limits
    assert any(a in (lim.az.min_steps, lim.az.max_steps) for a, _ in seen)  # it was clamped
    assert all(lim.az.min_steps <= a <= lim.az.max_steps and lim.el.min_steps <= e <= lim.el.max_steps
               for a, e in seen)


@pytest.mark.parametrize("value, rule", [(1.5, "less than or equal to 1"), ("high", "valid number")])
def test_bad_coarse_correction_threshold_is_refused_naming_the_key(tmp_path, capsys, value, rule):
    import yaml

    from controller.cli import main
    from tests.calibration.conftest import REPO

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
    from controller.reports.summary import coarse_summary

    runs = [NS(id=1, heliostat_id="H01", iterations=3), NS(id=2, heliostat_id="H02", iterations=1),
            NS(id=3, heliostat_id="H03", iterations=2)]
    moves = {1: [CorrectionRecord(0, "coarse", 0, 0, 0, 0), CorrectionRecord(1, "fine", 0, 0, 0, 0),
                 CorrectionRecord(2, "fine", 0, 0, 0, 0)],
             2: [], 3: [CorrectionRecord(1, "fine", 0, 0, 0, 0)]}
    store = NS(runs=lambda cid: runs, corrections=lambda rid: moves[rid])
    s = coarse_summary(store, 7, 0.5)
    assert (s["threshold"], s["applied"], s["iterations_mean"]) == (0.5, 1, 2.0)
    assert (s["iterations_mean_runs_with_coarse"], s["iterations_mean_runs_without_coarse"]) == (3.0, 1.5)
    # 4 moves over 3 heliostats; one first look was clipped (a move before any measurement).
    assert (s["corrections_mean"], s["clipped_first_looks"]) == (round(4 / 3, 3), 1)
    assert s["applied_heliostats"] == ["H01"]


def test_demo_recalibrates_only_the_heliostats_with_a_coarse_move_centroid_only(tmp_path, monkeypatch):
    from argparse import Namespace
    from types import SimpleNamespace as NS

    import controller.commands.campaigns._demo_coarse as demo_coarse
    import controller.commands.simulated as demo
    from tests.calibration.conftest import REPO

    def truth(err):
        return NS(label="x", error_before_mrad=5.0, error_after_mrad=err)

    sim = NS(result=NS(name="demo", runs=[NS(heliostat_id=h, iterations=i) for h, i in
                                          (("H01", 2), ("H02", 2), ("H03", 3))]),
             truth={"H01": truth(0.2), "H02": truth(0.3), "H03": truth(0.4)})
    asked = []

    def campaign(cfg, config_path, out, db, ids, settings, name, **kw):
        asked.append((list(ids), settings.seed, cfg.calibration.coarse_correction))
        again = NS(result=NS(runs=[NS(heliostat_id="H03", iterations=4)]), truth={"H03": truth(0.1)})
        return {}, again

    monkeypatch.setattr(demo, "simulated_campaign", campaign)
    cfg = NS(calibration=NS(coarse_correction=0.5))
    args = Namespace(seed=4, sequential=False)
    coarse = {"iterations_mean": 2.333, "applied_heliostats": ["H03"]}
    demo_coarse.centroid_only_twin(coarse, cfg, REPO / "configs" / "demo.yaml", tmp_path, sim, args)
    # Only H03 (coarse move) again, same seed, centroid only; the others count as they ran.
    assert asked == [(["H03"], 4, None)]
    assert coarse["iterations_centroid_only_mean"] == round((2 + 2 + 4) / 3, 3)
    assert coarse["centroid_only_rerun"] == ["H03"]
    assert coarse["error_after_centroid_only_mrad"]["max"] == 0.3
    # No coarse move: no second campaign, the run is its own centroid-only run.
    asked.clear()
    none = {"iterations_mean": 2.333, "applied_heliostats": []}
    demo_coarse.centroid_only_twin(none, cfg, REPO / "configs" / "demo.yaml", tmp_path, sim, args)
    assert asked == [] and none["centroid_only_rerun"] == []
    assert none["iterations_centroid_only_mean"] == 2.333


def test_demo_uncalibrated_field_runs_the_same_heliostats_with_and_without_the_coarse_correction(tmp_path,
                                                                                                 monkeypatch):

    import controller.commands.campaigns._demo_coarse as demo_coarse
    import controller.commands.simulated as demo
    from tests.calibration.conftest import REPO

    asked = []

    def campaign(cfg, config_path, out, db, ids, settings, name, **kw):
        c = cfg.calibration
        asked.append((list(ids), settings.seed, settings.tracking_error_mrad, c.coarse_correction,
                      c.standby_offset_m, Path(config_path).parent == Path(out)))
        with_coarse = c.coarse_correction is not None
        coarse = {"clipped_first_looks": 4, "applied": 3 if with_coarse else 0,
                  "applied_heliostats": ["H01"] if with_coarse else [],
                  "iterations_mean": 2.5 if with_coarse else 2.75,
                  "corrections_mean": 1.5 if with_coarse else 2.0}
        sim = SimpleNamespace(safety={"samples": 10, "violations": 0, "max_beams_on_target": 1},
                              result=SimpleNamespace(campaign_id=1),
                              on_target={"tower-target": [(0.0, 5.0, "H01")],
                                         "tower-lower": [(1.0, 1.5, "H02")]})
        return {"coarse_correction": coarse, "calibrated": 3, "heliostats_per_hour": 100.0, "db": str(db),
                "error_after_mrad": {"mean": 0.2, "max": 0.4}}, sim

    monkeypatch.setattr(demo, "simulated_campaign", campaign)
    import controller.reports.first_light as first_light

    report = {"heliostats": [], "totals": {"search_looks": 7, "search_s": 30.0}}
    monkeypatch.setattr(first_light, "first_light", lambda db, cid: report)
    monkeypatch.setattr(first_light, "write_first_light", lambda fl, folder: Path(folder) / "first-light.md")
    ids = ["H01", "H02", "H03"]
    u = demo_coarse.uncalibrated_field(REPO / "configs" / "demo.yaml", tmp_path, ids, 5, 12.0)
    threshold = load_config(REPO / "configs" / "demo.yaml").calibration.coarse_correction
    # Same heliostats, seed and hidden-error scale; the config's threshold, then none; beams parked
    # 16 m off (the demo config's 8 m is within reach of an uncalibrated field's errors).
    assert asked == [(["H01", "H02", "H03"], 5, 12.0, threshold, 16.0, True),
                     (["H01", "H02", "H03"], 5, 12.0, None, 16.0, True)]
    assert (u["applied"], u["iterations_mean"], u["iterations_centroid_only_mean"]) == (3, 2.5, 2.75)
    assert (u["corrections_mean"], u["corrections_centroid_only_mean"]) == (1.5, 2.0)
    assert (u["tracking_error_mrad"], u["heliostats"], u["clipped_first_looks"]) == (12.0, 3, 4)
    assert {"calibrated", "calibrated_centroid_only", "error_after_mrad", "error_after_centroid_only_mrad",
            "applied_heliostats", "threshold"} <= set(u)
    # The beam search a commissioning configuration turns on, told the field's σ at scale 12.
    assert u["search"] == {"max_looks": demo_coarse.SEARCH_LOOKS, "normal_sigma_mrad": 1.4 * 12.0}
    assert (u["search_steps"], u["search_s"], u["beam_safety"]["violations"]) == (7, 30.0, 0)
    assert (u["beam_safety"]["other_target_spans"], u["beam_safety"]["other_target_s"]) == (1, 0.5)


@pytest.mark.parametrize("value", ["0", "-3", "201", "nan", "realistic"])
def test_demo_refuses_a_bad_uncalibrated_scale_before_any_work(value, tmp_path, capsys):
    from controller.cli import main
    from tests.calibration.conftest import REPO

    config = str(REPO / "configs" / "demo.yaml")
    assert main(["demo", "--config", config, "--uncalibrated", value, "--out", str(tmp_path / "o")]) == 2
    out, err = capsys.readouterr()
    assert out == "" and len(err.strip().splitlines()) == 1 and "--uncalibrated" in err
    assert not (tmp_path / "o").exists()


def _measured(iteration: int, centroid) -> MeasurementRecord:
    return MeasurementRecord(iteration, 0, 0, (0.0, 1.0, 0.0), 0.0, 0.0, (0.0, 0.0, 30.0), 0.0,
                             centroid_enu=tuple(centroid))


class _Planner:
    """A pointing whose fine step is the offset itself (the move it plans is −offset)."""

    aim_point = np.array([0.0, 0.0, 30.0])

    def fine_correction(self, az, el, offset):
        return Step(0.0, 0.0, int(round(-1000 * offset[0])), int(round(-1000 * offset[2])))


def test_later_fine_steps_are_planned_by_the_first_steps_response():
    """The first fine step was to move the spot 2 m east and 1 m up and moved it 1.8 m east and
    1.1 m up (Eq. 1 of coarse.py): the next step, for a spot 0.2 m west of the aim, is planned so
    that the same response moves it 0.2 m east."""
    run = RunRecord("H01", 0, "running", "idle", 0, 0.0, 0.0)
    run.measurements = [_measured(1, (-2.0, 0.0, 29.0)), _measured(2, (-0.2, 0.0, 30.1))]
    run.corrections = [CorrectionRecord(1, "fine", 0.0, 0.0, 2000, 1000)]
    obs = Observation((0, 0), (-0.2, 0.0, 30.1), np.zeros(7), 1.0)
    kind, step = correction_step(_Planner(), 0, 0, obs, None, first=False, min_confidence=None, run=run)
    w, g = np.array([2.0, 0.0, 1.0]), np.array([1.8, 0.0, 1.1])
    planned = np.array([step.daz_steps, 0.0, step.del_steps]) / 1000.0  # the move it plans
    moved = planned + (g - w) * float(w @ planned) / float(w @ w)  # as the first step responded (M)
    assert kind == "fine" and moved == pytest.approx([0.2, 0.0, -0.1], abs=2e-3)
    assert (step.daz_steps, step.del_steps) != (200, -100)  # not the plain centroid step
    plain = correction_step(_Planner(), 0, 0, obs, None, first=False, min_confidence=None)[1]
    assert (plain.daz_steps, plain.del_steps) == (200, -100)
    run.corrections.insert(0, CorrectionRecord(1, "coarse", 0.0, 0.0, 1, 1))  # not one fine step: no response
    assert correction_step(_Planner(), 0, 0, obs, None, first=False, min_confidence=None, run=run)[1] == plain
