"""CLI contracts: heliocal merge, heliocal crf fit, heliocal report weighting."""

import csv
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from controller.cli import main
from simplant.devices.sensor import SensorModel, knee_response

DEMO = str(Path(__file__).resolve().parents[2] / "configs" / "demo.yaml")


def run(capsys, argv):
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def pair(tmp_path):
    low = np.array([[255, 5, 100], [40, 60, 250]], np.uint8)
    high = np.array([[255, 6, 200], [4, 120, 255]], np.uint8)
    cv2.imwrite(str(tmp_path / "low.png"), low)
    cv2.imwrite(str(tmp_path / "high.png"), high)
    return tmp_path


@pytest.mark.parametrize("ext", [".npy", ".tiff"])
def test_merge_json_contract(capsys, pair, ext):
    out = pair / f"hdr{ext}"
    code, stdout, _ = run(capsys, ["merge", str(pair / "low.png"), str(pair / "high.png"),
                                   "--exposures", "0.010", "0.020", "--out", str(out), "--json"])
    assert code == 0
    info = json.loads(stdout)
    assert set(info) == {"shape", "min", "max", "saturated_both", "saturated_px", "dark_both",
                         "inconsistent_fraction", "preview"}
    # lit and unsaturated in both: (0, 2), (1, 0), (1, 1); (1, 0) is 40 in LOW but 4 in HIGH
    assert info["saturated_px"] == info["saturated_both"]
    assert info["inconsistent_fraction"] == pytest.approx(1 / 3)
    assert Path(info["preview"]).is_file() and Path(info["preview"]).suffix == ".png"
    assert info["shape"] == [2, 3] and info["saturated_both"] == 1 and info["dark_both"] == 2
    img = np.load(out) if ext == ".npy" else cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.float32 and img.shape == (2, 3)
    assert img.max() == pytest.approx(info["max"]) and np.all(np.isfinite(img))
    assert img[0, 0] == pytest.approx(255 / 0.010)  # linear CRF: I(255)/t1


def test_merge_with_crf_and_weighting(capsys, pair, tmp_path):
    from controller.imaging.crf import Crf

    Crf.linear(8, 8.0).save(tmp_path / "crf.yaml")
    code, stdout, _ = run(capsys, ["merge", str(pair / "low.png"), str(pair / "high.png"), "--exposures",
                                   "0.01", "0.02", "--crf", str(tmp_path / "crf.yaml"), "--weighting",
                                   "noise-optimal", "--out", str(tmp_path / "o.npy"), "--json"])
    assert code == 0 and json.loads(stdout)["min"] == 0.0


@pytest.mark.parametrize("argv_tail, msg", [
    (["--exposures", "0.02", "0.01", "--out", "o.npy"], "LOW <= HIGH"),
    (["--exposures", "0.01", "0.02", "--out", "o.png"], ".npy or .tiff"),
    (["--exposures", "0.01", "0.02", "--out", "o.npy", "--crf", "missing.yaml"], "CRF file not found"),
])
def test_merge_bad_input_exit_2_nothing_written(capsys, pair, monkeypatch, argv_tail, msg):
    monkeypatch.chdir(pair)
    code, _, err = run(capsys, ["merge", "low.png", "high.png", *argv_tail])
    assert code == 2 and msg in err and len(err.strip().splitlines()) == 1
    assert not (pair / "o.npy").exists() and not (pair / "o.png").exists()


def test_merge_size_mismatch_json_error(capsys, pair):
    cv2.imwrite(str(pair / "small.png"), np.zeros((1, 3), np.uint8))
    code, stdout, _ = run(capsys, ["merge", str(pair / "low.png"), str(pair / "small.png"), "--exposures",
                                   "0.01", "0.02", "--out", str(pair / "o.npy"), "--json"])
    assert code == 2
    res = json.loads(stdout)
    assert res["ok"] is False and "differ in size" in res["error"]
    assert not (pair / "o.npy").exists()


def test_crf_fit_cli(capsys, tmp_path):
    rng = np.random.default_rng(0)
    lines = ["sensor,exposure_value,pixel_mean"]
    for name, s in (("ccd1", SensorModel(response=knee_response(0.15))),
                    ("ccd2", SensorModel(response=knee_response(0.25), gain=1.03))):
        for x in np.linspace(0, 300, 30):
            lines.append(f"{name},{x},{min(float(s.expected_value(x, 1.0)) + rng.normal(0, 0.3), 255)}")
    (tmp_path / "d.csv").write_text("\n".join(lines))
    code, stdout, _ = run(capsys, ["crf", "fit", str(tmp_path / "d.csv"), "--out", str(tmp_path / "c.yaml"),
                                   "--json"])
    assert code == 0
    res = json.loads(stdout)
    assert [s["name"] for s in res["sensors"]] == ["ccd1", "ccd2"]
    assert all(0 < s["uncertainty_pct"] < 3 for s in res["sensors"])
    assert (tmp_path / "c.yaml").is_file() and res["plot"] == str(tmp_path / "c.png")
    assert (tmp_path / "c.png").read_bytes()[:4] == b"\x89PNG"  # the fit against the data, to look at
    code, _, err = run(capsys, ["crf", "fit", str(tmp_path / "none.csv"), "--out", str(tmp_path / "x.yaml")])
    assert code == 2 and "not found" in err and not (tmp_path / "x.yaml").exists()


def test_report_weighting_contract(capsys, tmp_path):
    out = tmp_path / "study"
    code, stdout, _ = run(capsys, ["report", "weighting", "--pairs", "3", "--out", str(out), "--seed", "1",
                                   "--config", DEMO, "--json"])
    assert code == 0
    res = json.loads(stdout)
    assert res["thresholds"] == [0.45, 0.5, 0.55, 0.6, 0.65, 0.7, 0.75, 0.8, 0.85, 0.9]
    assert set(res["rms_px"]) == {"raised-cosine", "robertson", "debevec", "mitsunaga", "reinhard",
                                  "deneve", "noise-optimal"}
    assert all(len(v) == 10 and all(r >= 0 for r in v) for v in res["rms_px"].values())
    for name in ("rms_vs_threshold.png", "weighting_functions.png", "profiles.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rows = list(csv.DictReader((out / "weighting_study.csv").open()))
    assert len(rows) == 70 and float(rows[0]["rms_px"]) == pytest.approx(res["rms_px"]["raised-cosine"][0],
                                                                          abs=1e-5)
    code, _, err = run(capsys, ["report", "weighting", "--pairs", "1", "--out", str(out), "--config", DEMO])
    assert code == 2 and "--pairs" in err


def test_merge_refuses_a_swapped_pair_and_mismatched_depths(capsys, tmp_path):
    yy, xx = np.mgrid[0:60, 0:80]
    spot = 150.0 * np.exp(-((xx - 40.0) ** 2 + (yy - 30.0) ** 2) / 200.0)
    low = (10 + spot).astype(np.uint8)
    high = np.clip(10 + 1.8 * spot, 0, 255).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "low.png"), low)
    cv2.imwrite(str(tmp_path / "high.png"), high)
    cv2.imwrite(str(tmp_path / "high16.png"), high.astype(np.uint16) * 256)
    swapped = ["merge", str(tmp_path / "high.png"), str(tmp_path / "low.png"), "--exposures", "0.01", "0.02",
               "--out", str(tmp_path / "s.npy")]
    code, _, err = run(capsys, swapped)
    assert code == 2 and "brighter in LOW than in HIGH: swapped" in err and not (tmp_path / "s.npy").exists()
    mixed = ["merge", str(tmp_path / "low.png"), str(tmp_path / "high16.png"), "--exposures", "0.01", "0.02",
             "--out", str(tmp_path / "m.npy")]
    code, _, err = run(capsys, mixed)
    assert code == 2 and "uint8" in err and "uint16" in err and not (tmp_path / "m.npy").exists()
    ok = ["merge", str(tmp_path / "low.png"), str(tmp_path / "high.png"), "--exposures", "0.01", "0.02",
          "--out", str(tmp_path / "ok.npy"), "--json"]
    code, out, _ = run(capsys, ok)
    assert code == 0 and json.loads(out)["inconsistent_fraction"] < 0.01


@pytest.mark.parametrize("args, option", [
    (["merge", "L", "H", "--exposures", "0.01", "0.02", "--out", "{tmp}/no/dir/o.npy"], "--out"),
    (["crf", "fit", "D.csv", "--out", "{tmp}/no/dir/crf.yaml"], "--out"),
    (["library", "build", "M.csv", "--out", "{tmp}"], "--out"),
    (["beam", "I.png", "--plot", "{tmp}/no/dir/plots"], "--plot"),
])
def test_output_paths_are_checked_before_any_work(capsys, tmp_path, args, option):
    code, _, err = run(capsys, [a.replace("{tmp}", str(tmp_path)) for a in args])
    assert code == 2 and option in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_documented_example_runs(capsys, tmp_path):
    """docs/imaging.md: heliocal crf fit docs/examples/sphere.csv --out crf.yaml"""
    sample = Path(__file__).resolve().parents[2] / "docs" / "examples" / "sphere.csv"
    code, stdout, _ = run(capsys, ["crf", "fit", str(sample), "--out", str(tmp_path / "crf.yaml"), "--json"])
    assert code == 0 and len(json.loads(stdout)["sensors"]) == 2
