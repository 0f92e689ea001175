"""Recognition that generalises: error cases at several magnitudes and heliostats, whitening,
the magnitude estimate, and the held-out splits of ``heliocal report confusion``."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from beamkit import cli

from controller.errors import InputError
from controller.recognition.library import Entry, Library, Spread, whitening
from controller.recognition.library_io import load_library, read_manifest, save_library
from controller.recognition.splits import Coverage


@pytest.fixture(scope="module")
def multi_set(tmp_path_factory):
    """3 cases; library on H03, H15 at magnitudes 0.5 and 1.5; test views on H09 (held out) and
    H15 with magnitudes drawn from 0.5..1.5."""
    out = tmp_path_factory.mktemp("multi")
    from controller.cli import main

    code = main(["sim", "errorset", "--out", str(out), "--cases", "3", "--heliostat", "H03,H15",
                 "--magnitudes", "0.5,1.5", "--views", "3", "--test-heliostats", "H09,H15",
                 "--test-magnitudes", "0.5,1.5", "--json"])
    assert code == 0
    return out


def test_error_case_scaled_scales_every_mechanism():
    from simplant.errorset import CASES

    by = {c.label: c for c in CASES}
    wind = by["wind-load"].scaled(0.5)
    assert wind.params.el_offset == pytest.approx(0.5e-3) and wind.magnitude == 0.5
    x, y = np.array([0.5, -1.0]), np.array([1.0, 0.3])
    np.testing.assert_allclose(wind.deformation(x, y)[0], 0.5 * by["wind-load"].deformation(x, y)[0])
    assert by["gear-backlash"].scaled(1.5).rock_az_rad == pytest.approx(90e-3)
    assert by["defocus"].scaled(0.5).focus_factor == pytest.approx(1.3)
    assert by["tracking-offset"].scaled(2.0).params.tilt_east == pytest.approx(4e-3)
    assert by["canting-error"].scaled(1.5).error_params() == {"magnitude": 1.5}
    assert by["tracking-offset"].error_params()["az_offset_mrad"] == pytest.approx(3.0)
    with pytest.raises(ValueError):
        by["wind-load"].scaled(0.0)


def test_multi_errorset_library_splits_and_estimate(multi_set, tmp_path, capsys):
    lib_rows, test_rows = read_manifest(multi_set / "library.csv"), read_manifest(multi_set / "test.csv")
    assert len(lib_rows) == 3 * 2 * 2 and len(test_rows) == 3 * 2 * 3
    assert {r.extra["heliostat"] for r in lib_rows} == {"H03", "H15"}
    assert {float(r.extra["magnitude"]) for r in lib_rows} == {0.5, 1.5}
    assert all(0.5 <= float(r.extra["magnitude"]) <= 1.5 for r in test_rows)
    assert {r.extra["source"] for r in lib_rows + test_rows} == {"lamp"}
    # The pointing error grows with the magnitude: tracking-offset at 1.5 is ~3x the one at 0.5.
    track = {float(r.extra["magnitude"]): r.az_deg for r in lib_rows
             if r.label == "tracking-offset" and r.extra["heliostat"] == "H15"}
    assert track[1.5] == pytest.approx(3 * track[0.5], rel=1e-2)

    lib_path = tmp_path / "lib.yaml"
    code, out, err = cli(capsys, "library", "build", str(multi_set / "library.csv"), "--out", str(lib_path),
                         "--json")
    assert code == 0, err
    assert json.loads(out)["features"] == "multi-lobe-hu"
    doc = yaml.safe_load(lib_path.read_text())
    assert doc["thresholds"] == [0.1, 0.3, 0.5, 0.1] and len(doc["normalisation"]["whiten"]) == 28
    assert doc["entries"][0]["params"]["heliostat"] == "H03" and len(doc["entries"][0]["features"]) == 28

    code, out, err = cli(capsys, "report", "confusion", "--library", str(lib_path), "--test",
                         str(multi_set / "test.csv"), "--out", str(tmp_path / "rep"), "--json")
    assert code == 0, err
    d = json.loads(out)
    assert set(d["splits"]) == {"held-out-heliostat", "held-out-magnitude"}
    assert d["splits"]["held-out-heliostat"]["n"] == 9 and d["splits"]["held-out-magnitude"]["n"] == 9
    assert sum(s["tp"] for s in d["splits"].values()) == d["tp"]
    assert d["unknown_rate"] == pytest.approx(d["unknown"] / d["n"])
    for s in d["splits"].values():
        assert {"matrix", "recall", "fnr", "per_class", "unknown_rate", "recognition_rate"} <= set(s)
    md = (tmp_path / "rep" / "confusion.md").read_text()
    assert "## Split: held-out-heliostat (9 views)" in md and "| TPR | FNR |" in md

    row = next(r for r in test_rows if r.label == "gear-backlash")
    code, out, err = cli(capsys, "match", str(row.image), "--library", str(lib_path), "--json")
    assert code == 0, err
    m = json.loads(out)
    assert {"error_deg", "coarse_correction_deg", "magnitude", "confidence", "nearest"} <= set(m)
    assert 0.0 <= m["confidence"] <= 1.0
    if not m["unknown"]:
        assert m["coarse_correction_deg"] == [-m["error_deg"][0], -m["error_deg"][1]]
        assert 0.5 <= m["magnitude"] <= 1.5


def _line_library() -> Library:
    """Case 'a' at magnitudes 0.5, 1, 1.5 on a line in feature space; case 'b' far away."""
    f = np.zeros(7)
    entries = [Entry("a", f + [0.10 * m, 0, 0, 0, 0, 0, 0], az_deg=0.2 * m, el_deg=-0.1 * m,
                     params={"magnitude": m}) for m in (0.5, 1.0, 1.5)]
    entries.append(Entry("b", f + [0, 1.0, 0, 0, 0, 0, 0], az_deg=0.0, el_deg=0.0, params={"magnitude": 1.0}))
    for e in entries:
        e.unknown_distance = 0.2
    return Library(features="hu", threshold=0.5, entries=entries)


def test_estimate_interpolates_between_neighbouring_entries():
    lib = _line_library()
    at = lib.match_hu(np.array([0.10, 0, 0, 0, 0, 0, 0]))
    assert at.label == "a" and at.error_deg == pytest.approx((0.2, -0.1), abs=1e-9)
    assert at.magnitude == pytest.approx(1.0) and at.coarse_correction_deg == pytest.approx((-0.2, 0.1))
    # Between magnitudes 1 and 1.5, nearer to 1.5: the estimate lies between, nearer 1.5.
    q = lib.match_hu(np.array([0.14, 0, 0, 0, 0, 0, 0]))
    assert 1.25 < q.magnitude < 1.5 and 0.25 < q.error_deg[0] < 0.3
    # Confidence: high well inside the threshold and far from case b; 0 when unknown.
    assert at.confidence == pytest.approx(1.0) and 0 < q.confidence <= 1
    far = lib.match_hu(np.array([0.10, 0.5, 0, 0, 0, 0, 0]))
    assert far.unknown and far.confidence == 0.0 and far.error_deg is None


def test_whitening_makes_the_within_case_spread_isotropic():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(200, 3)) * [1e-1, 1e-2, 1e-3]
    dev = rng.normal(size=(50, 3)) * [1e-4, 1e-3, 1e-5]
    w = whitening(x, Spread(dev, np.zeros(50, dtype=np.int64)))
    c = dev.T @ dev / 50
    np.testing.assert_allclose(w @ c @ w.T, np.eye(3), atol=1e-6)
    # The entries' own spread (how the cases differ) is not shrunk: the direction in which the
    # nuisance varies least weighs most.
    assert np.linalg.norm(w @ [0, 0, 1.0]) > 10 * np.linalg.norm(w @ [0, 1.0, 0])
    # A direction in which the library does not vary (variance below 1e-6 of the largest) is
    # not blown up beyond 1/sqrt(1e-6 x largest).
    flat = np.c_[x[:, :2], np.full(200, 0.5)]
    w = whitening(flat, Spread(np.zeros((0, 3)), np.zeros(0, dtype=np.int64)))
    lam_max = np.linalg.eigvalsh(np.cov(flat.T, bias=True)).max()
    assert np.linalg.norm(w @ [0, 0, 1.0]) == pytest.approx(1 / np.sqrt(1e-6 * lam_max), rel=1e-6)


def test_coverage_assigns_splits():
    entries = [Entry("a", np.zeros(7), params={"heliostat": "H01", "source": "lamp", "magnitude": 1.0})]
    cov = Coverage.of(entries)
    assert cov.split("a", {"heliostat": "H01", "source": "lamp", "magnitude": "1.0"}) == "seen"
    assert cov.split("a", {"heliostat": "H01", "source": "lamp", "magnitude": "0.8"}) == "held-out-magnitude"
    assert cov.split("a", {"heliostat": "H02", "source": "lamp", "magnitude": "1.0"}) == "held-out-heliostat"
    assert cov.split("a", {"heliostat": "H01", "source": "sun", "magnitude": "1.0"}) == "held-out-geometry"
    assert cov.split("a", {}) is None
    assert Coverage.of([Entry("a", np.zeros(7))]).split("a", {"heliostat": "H01"}) is None


def test_library_file_keeps_whitening_and_params_and_rejects_bad_whiten(multi_set, tmp_path):
    from controller.recognition.library_io import build_library_from_manifest

    lib = build_library_from_manifest(multi_set / "library.csv", "multi-hu")
    save_library(lib, tmp_path / "lib.yaml")
    back = load_library(tmp_path / "lib.yaml")
    np.testing.assert_allclose(back.whiten, lib.whiten)
    assert back.entries[3].params == lib.entries[3].params
    img = np.load(read_manifest(multi_set / "test.csv")[0].image)
    assert back.match_image(img) == lib.match_image(img)
    with pytest.raises(InputError, match="needs Hu moments at thresholds"):
        lib.match_hu(np.ones(7))
    doc = yaml.safe_load((tmp_path / "lib.yaml").read_text())
    doc["normalisation"]["whiten"] = [[1.0, 0.0]]
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(InputError, match=r"bad.yaml: normalisation.whiten must be a 21 x 21"):
        load_library(tmp_path / "bad.yaml")


@pytest.mark.parametrize("args, message", [
    (["--heliostat", "H99"], "heliostat 'H99'"),
    (["--sources", "moon"], "light source 'moon'"),
    (["--magnitudes", "0.5,x"], "--magnitudes"),
    (["--magnitudes", "-1"], "--magnitudes"),
    (["--test-magnitudes", "1.5,0.5"], "--test-magnitudes"),
])
def test_errorset_bad_generalisation_options(tmp_path, capsys, args, message):
    out = tmp_path / "x"
    code, _, err = cli(capsys, "sim", "errorset", "--out", str(out), *args)
    assert code == 2 and message in err
    assert not out.exists() or not any(out.iterdir())


def test_add_reference_to_a_multi_hu_library_describes_the_frame(multi_set, tmp_path):
    from controller.imaging.beam import analyze
    from controller.recognition.library_io import add_reference, build_library_from_manifest

    lib = build_library_from_manifest(multi_set / "library.csv", "multi-hu")
    save_library(lib, tmp_path / "lib.yaml")
    frame = np.load(read_manifest(multi_set / "test.csv")[-1].image)
    add_reference(tmp_path / "lib.yaml", "new-case", frame, analyze(frame).hu, source="H09", threshold=0.5)
    back = load_library(tmp_path / "lib.yaml")
    assert len(back.entries[-1].features) == 21
    m = back.match_image(frame)
    assert (m.label, m.index) == ("new-case", len(back.entries) - 1)
    assert m.distance == pytest.approx(0, abs=1e-9)
