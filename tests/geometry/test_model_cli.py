"""``heliocal model fit|predict|validate`` on the real AA39 records (issue #12 contract)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from controller.cli import main
from controller.geometry.frames import enu_to_wgs84, wgs84_to_enu
from controller.geometry.model.tracking import TERMS

AA39 = Path(__file__).resolve().parents[1] / "data" / "real" / "aa39"
PROPS = str(AA39 / "AA39-heliostat-properties.json")
TOWERS = str(AA39 / "tower-measurements.json")
RECORDS = [str(AA39 / f"AA39-calibration-properties_{i}.json") for i in (1, 2, 3)]
DOC_KEYS = {"format", "heliostat", "origin_wgs84", "terms", "sigma", "prior_sigma", "identified",
            "covariance_si", "noise_mrad", "noise_scale", "condition", "converged", "training"}
TERM_KEYS = [f"{t.name}_{t.unit}" for t in TERMS]
N = len(TERMS)
FIT = ["model", "fit", "--heliostat-properties", PROPS, "--towers", TOWERS]


def run_json(capsys, argv: list[str]) -> tuple[int, dict]:
    code = main([*argv, "--json"])
    return code, json.loads(capsys.readouterr().out)


def fit(capsys, tmp_path: Path, records: list[str], name: str = "MODEL.json") -> tuple[Path, dict]:
    out = tmp_path / name
    code, doc = run_json(capsys, [*FIT, *records, "--out", str(out)])
    assert code == 0
    return out, doc


def predict(capsys, model: Path, record: str) -> dict:
    code, out = run_json(capsys, ["model", "predict", str(model), "--record", record, "--towers", TOWERS])
    assert code == 0
    return out


def test_fit_writes_the_documented_model_file(capsys, tmp_path):
    out, doc = fit(capsys, tmp_path, RECORDS)
    assert json.loads(out.read_text()) == doc  # --json prints the file's document
    assert DOC_KEYS <= set(doc)
    assert doc["format"] == "heliocal-tracking-model/1"
    assert doc["heliostat"]["id"] == "AA39"
    assert doc["heliostat"]["properties"] == json.loads(Path(PROPS).read_text())
    assert list(doc["terms"]) == TERM_KEYS and list(doc["sigma"]) == TERM_KEYS
    assert doc["prior_sigma"]["az_offset_mrad"] == 15.0 and doc["prior_sigma"]["el_pivot_radius_mm"] == 1.0
    assert "az_offset" in doc["identified"]
    assert np.asarray(doc["covariance_si"]).shape == (N, N)
    assert doc["noise_mrad"] == 0.8
    t = doc["training"]
    assert t["records"] == [Path(r).name for r in RECORDS]
    assert len(t["residual_mrad"]) == len(t["robust_weights"]) == 3
    assert t["initial_residual_mrad_rms"] == pytest.approx(13.9, abs=0.5)  # docs/geometry.md
    assert t["residual_mrad_rms"] < 0.2 * t["initial_residual_mrad_rms"]
    # σ are the square roots of the covariance's diagonal (mrad / mm vs SI).
    assert [doc["sigma"][k] for k in TERM_KEYS] == pytest.approx(1e3 * np.sqrt(np.diag(doc["covariance_si"])))


def test_fit_prints_terms_with_sigma_and_residuals(capsys, tmp_path):
    out = tmp_path / "m.json"
    assert main([*FIT, *RECORDS, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert out.is_file() and str(out) in text
    for key in TERM_KEYS:
        assert key in text
    assert "identified" in text and "no (prior)" in text
    assert "training residual (normal, mrad)" in text and "nominal 13.8" in text


def test_predict_follows_the_contract(capsys, tmp_path):
    model, doc = fit(capsys, tmp_path, RECORDS[:2])
    p = predict(capsys, model, RECORDS[2])
    record = json.loads(Path(RECORDS[2]).read_text())
    assert {"focal_spot_wgs84", "focal_spot_enu_m", "target"} <= set(p)
    assert p["target"] == record["target_name"]
    assert len(p["focal_spot_wgs84"]) == len(p["focal_spot_enu_m"]) == 3
    origin = doc["origin_wgs84"]
    back = enu_to_wgs84(p["focal_spot_enu_m"], *origin)
    assert p["focal_spot_wgs84"] == pytest.approx(list(back), abs=1e-9)
    # On the target plane (the Jülich targets face north: a plane of constant north).
    tower = json.loads(Path(TOWERS).read_text())[record["target_name"]]
    plane_n = wgs84_to_enu(*tower["coordinates"]["center"], *origin)[1]
    assert p["focal_spot_enu_m"][1] == pytest.approx(plane_n, abs=1e-6)


def test_predict_does_not_read_the_focal_spot(capsys, tmp_path):
    model, _ = fit(capsys, tmp_path, RECORDS[:2])
    with_spot = predict(capsys, model, RECORDS[2])
    record = json.loads(Path(RECORDS[2]).read_text())
    del record["focal_spot"]
    without = tmp_path / "no-spot.json"
    without.write_text(json.dumps(record))
    assert predict(capsys, model, str(without))["focal_spot_enu_m"] == with_spot["focal_spot_enu_m"]
    record["focal_spot"] = {"UTIS": [0.0, 0.0, 0.0]}  # a wrong spot changes nothing either
    without.write_text(json.dumps(record))
    assert predict(capsys, model, str(without))["focal_spot_enu_m"] == with_spot["focal_spot_enu_m"]


@pytest.mark.parametrize("held_out", [0, 1, 2])
def test_prediction_from_the_other_two_records_beats_the_nominal_kinematics(capsys, tmp_path, aa39,
                                                                            aa39_records, held_out):
    others = [r for i, r in enumerate(RECORDS) if i != held_out]
    model, _ = fit(capsys, tmp_path, others)
    got = np.asarray(predict(capsys, model, RECORDS[held_out])["focal_spot_enu_m"])
    r = aa39_records[held_out]
    nominal = aa39.spot(r["az_steps"], r["el_steps"], r["sun"], r["plane_point"], r["plane_normal"])
    miss, nominal_miss = np.linalg.norm(got - r["spot"]), np.linalg.norm(nominal - r["spot"])
    assert miss < 0.5 * nominal_miss, (miss, nominal_miss)
    assert nominal_miss > 0.5  # metres: the uncalibrated miss the model closes


def test_validate_json_beats_uncalibrated_by_four_on_every_fold(capsys):
    code, out = run_json(capsys, ["model", "validate", *RECORDS, "--heliostat-properties", PROPS,
                                  "--towers", TOWERS])
    assert code == 0
    assert [f["record"] for f in out["folds"]] == [Path(r).name for r in RECORDS]
    for f in out["folds"]:
        assert f["held_out_mrad"] * 4.0 < f["uncalibrated_mrad"], f
        assert 0.0 < f["methods_disagree_mrad"] < 1.0  # UTIS vs HeliOS: the floor
        assert "az_offset" in f["identified"]
    assert out["held_out_rms_mrad"] == pytest.approx(1.58, abs=0.05)  # docs/tracking-model.md table
    assert out["uncalibrated_rms_mrad"] == pytest.approx(13.83, abs=0.05)
    assert out["worst_ratio"] > 4.0


def test_validate_text_table(capsys):
    assert main(["model", "validate", *RECORDS, "--heliostat-properties", PROPS, "--towers", TOWERS]) == 0
    text = capsys.readouterr().out
    assert all(Path(r).name in text for r in RECORDS)
    assert "held out vs" in text and "uncalibrated" in text


def test_predict_through_the_installed_entry_point(tmp_path):
    """The contract as a script sees it: a separate process, JSON on stdout."""
    model = tmp_path / "m.json"
    res = subprocess.run([sys.executable, "-m", "controller.cli", *FIT, *RECORDS[:2], "--out", str(model)],
                         capture_output=True, text=True, timeout=120, check=False)
    assert res.returncode == 0, res.stderr
    res = subprocess.run([sys.executable, "-m", "controller.cli", "model", "predict", str(model), "--record",
                          RECORDS[2], "--towers", TOWERS, "--json"], capture_output=True, text=True,
                         timeout=120, check=False)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["target"] == "multi_focus_tower"


# --- bad inputs: exit 2, one line naming the file/key, nothing written ---------------------

def _edited_record(tmp_path: Path, edit) -> str:
    record = json.loads(Path(RECORDS[0]).read_text())
    edit(record)
    path = tmp_path / "edited-record.json"
    path.write_text(json.dumps(record))
    return str(path)


def _fit_fails(capsys, tmp_path, records, *, props=PROPS, towers=TOWERS) -> str:
    out = tmp_path / "out" / "MODEL.json"
    out.parent.mkdir(exist_ok=True)
    code, err = run_json(capsys, ["model", "fit", *records, "--heliostat-properties", props,
                                  "--towers", towers, "--out", str(out)])
    assert code == 2 and err["ok"] is False
    assert list(out.parent.iterdir()) == []  # nothing written, no temporary left behind
    return err["error"]


def test_fit_names_a_missing_record_key(capsys, tmp_path):
    bad = _edited_record(tmp_path, lambda r: r["motor_position"].pop("axis_1_motor_position"))
    msg = _fit_fails(capsys, tmp_path, [RECORDS[1], bad])
    assert bad in msg and "motor_position.axis_1_motor_position" in msg


def test_fit_names_a_bad_target(capsys, tmp_path):
    bad = _edited_record(tmp_path, lambda r: r.update(target_name="no_such_target"))
    msg = _fit_fails(capsys, tmp_path, [bad])
    assert bad in msg and "'no_such_target'" in msg and "solar_tower_juelich_upper" in msg


def test_a_record_with_one_spot_method_is_fitted_with_it_and_said(capsys, tmp_path):
    """A record with only HeliOS's spot takes HeliOS's and says so on stderr; a record with
    neither method's spot is refused, naming both."""
    helios = _edited_record(tmp_path, lambda r: r["focal_spot"].pop("UTIS"))
    out = tmp_path / "m.json"
    code = main(["model", "fit", helios, *RECORDS[1:], "--heliostat-properties", PROPS, "--towers", TOWERS,
                 "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 0 and "no UTIS spot; HeliOS's used" in err and "edited-record.json" in err
    neither = _edited_record(tmp_path, lambda r: r.pop("focal_spot") and r.update(focal_spot={}))
    assert "focal_spot.UTIS" in _fit_fails(capsys, tmp_path, [neither]) and "HeliOS" in _fit_fails(
        capsys, tmp_path, [neither])


def test_fit_names_a_bad_properties_key(capsys, tmp_path):
    props = json.loads(Path(PROPS).read_text())
    del props["kinematics_properties"]["actuators"][1]["pivot_radius"]
    path = tmp_path / "props.json"
    path.write_text(json.dumps(props))
    msg = _fit_fails(capsys, tmp_path, RECORDS, props=str(path))
    assert str(path) in msg and "pivot_radius" in msg


def test_fit_rejects_an_out_path_in_a_missing_folder(capsys, tmp_path):
    out = tmp_path / "missing" / "MODEL.json"
    code, err = run_json(capsys, [*FIT, *RECORDS, "--out", str(out)])
    assert code == 2 and "--out" in err["error"] and not out.parent.exists()


def test_predict_rejects_a_file_that_is_not_a_model(capsys, tmp_path):
    code, err = run_json(capsys, ["model", "predict", RECORDS[0], "--record", RECORDS[1], "--towers", TOWERS])
    assert code == 2 and RECORDS[0] in err["error"] and "not a heliocal model file" in err["error"]


@pytest.mark.parametrize("edit, match", [
    (lambda d: d["terms"].update(spin_mrad=1.0), "unknown term 'spin_mrad'"),
    (lambda d: d.pop("covariance_si"), "missing key 'covariance_si'"),
    (lambda d: d.update(covariance_si=[[0.0] * N] * (N - 1)), f"covariance_si must be a {N}×{N} matrix"),
    (lambda d: d["heliostat"]["properties"].pop("heliostat_position"), "heliostat_position"),
])
def test_predict_names_a_bad_model_key(capsys, tmp_path, edit, match):
    model, doc = fit(capsys, tmp_path, RECORDS[:2])
    edit(doc)
    model.write_text(json.dumps(doc))
    code, err = run_json(capsys, ["model", "predict", str(model), "--record", RECORDS[2], "--towers", TOWERS])
    assert code == 2 and str(model) in err["error"] and match in err["error"]


def test_validate_needs_two_records(capsys):
    code, err = run_json(capsys, ["model", "validate", RECORDS[0], "--heliostat-properties", PROPS,
                                  "--towers", TOWERS])
    assert code == 2 and "at least two records" in err["error"]
