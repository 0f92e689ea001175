"""Library, Euclidean matching, confusion report: hand-built cases, the paper's numbers, bad input,
and the recognition bar on the default rendered error set (both feature kinds)."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import yaml
from beamkit import cli, gaussian

from controller.errors import InputError
from controller.recognition.confusion import confusion
from controller.recognition.library import hu_features
from controller.recognition.library_io import load_library, read_manifest
from controller.recognition.matching import Matcher


def test_matcher_nearest_runner_up_and_unknown():
    feats = np.array([[0.0, 0, 0, 0, 0, 0, 0], [1.0, 0, 0, 0, 0, 0, 0], [0.0, 3, 0, 0, 0, 0, 0],
                      [0.2, 0, 0, 0, 0, 0, 0]])
    m = Matcher(feats, ["a", "b", "c", "a"], unknown_distance=0.5)
    q = np.array([0.3, 0.4, 0, 0, 0, 0, 0])
    r = m.match(q)
    # |q - a2| = hypot(0.1, 0.4); nearest other label is b at hypot(0.7, 0.4) (Eq. 14).
    assert (r.label, r.index) == ("a", 3)
    assert r.distance == pytest.approx(np.hypot(0.1, 0.4))
    assert (r.runner_up_label, r.runner_up_distance) == ("b", pytest.approx(np.hypot(0.7, 0.4)))
    assert not r.unknown
    assert m.match(np.array([5.0, 5, 0, 0, 0, 0, 0])).unknown


def test_matcher_scale_divides_features():
    m = Matcher(np.array([[1.0, 0, 0, 0, 0, 0, 0], [0.0, 10, 0, 0, 0, 0, 0]]), ["x", "y"],
                scale=np.array([1.0, 100, 1, 1, 1, 1, 1]))
    # Scaled, y sits at (0, 0.1): nearer to the origin than x at (1, 0).
    assert m.match(np.zeros(7)).label == "y"


def test_matcher_100k_entries_agrees_with_brute_force():
    rng = np.random.default_rng(0)
    feats = rng.normal(size=(100_000, 7))
    labels = [f"c{i % 50}" for i in range(100_000)]
    m = Matcher(feats, labels)
    q = rng.normal(size=7)
    d = np.linalg.norm(feats - q, axis=1)
    r = m.match(q)
    assert r.index == int(np.argmin(d)) and r.distance == pytest.approx(d.min())


def test_log_hu_features():
    h = np.array([1e-1, -1e-3, 1e-7, 0.0, 2e-12, -5e-9, 1e-20])
    f = hu_features(h, "log-hu")
    expected = [1.0, -3.0, 7.0, 0.0, 12 - np.log10(2), -(9 - np.log10(5)), 20.0]
    np.testing.assert_allclose(f, expected, atol=1e-12)
    np.testing.assert_array_equal(hu_features(h, "hu"), h)
    with pytest.raises(InputError):
        hu_features(h, "zernike")


def test_paper_table4_numbers():
    # 6 cases x 14 views, TP 79 and FN 5 -> recall 0.9405, FNR 0.0595, 94.0476 %.
    labels = [f"case{i}" for i in range(6)]
    true = [lab for lab in labels for _ in range(14)]
    pred = list(true)
    pred[0], pred[15], pred[30] = "case1", "case2", "unknown"
    pred[45], pred[60] = "case0", "unknown"
    c = confusion(true, pred, labels)
    assert (c.tp, c.fn) == (79, 5)
    assert c.recall == pytest.approx(79 / 84) and c.fnr == pytest.approx(5 / 84)
    assert c.recognition_rate == pytest.approx(94.0476, abs=1e-4)
    assert c.matrix[0, 1] == 1 and c.unknown[2] == 1 and c.matrix.sum() == 82


def _manifest(tmp_path, rows, header="image,label,az_deg,el_deg"):
    p = tmp_path / "m.csv"
    p.write_text(header + "\n" + "\n".join(rows) + "\n")
    return p


def test_manifest_errors_name_file_and_line(tmp_path):
    with pytest.raises(InputError, match="missing label"):
        read_manifest(_manifest(tmp_path, ["a.npy,x,1,2"], header="image,az_deg"))
    with pytest.raises(InputError, match=r"m.csv:3: az_deg is not a number"):
        read_manifest(_manifest(tmp_path, ["a.npy,x,1,2", "b.npy,y,east,2"]))
    rows = read_manifest(_manifest(tmp_path, ["a.npy,x,,", "sub/b.npy,y,1.5,-2"]))
    assert rows[0].az_deg is None and rows[1].el_deg == -2.0
    assert rows[1].image == tmp_path / "sub" / "b.npy"


def _spot_library(tmp_path, capsys, kind="hu"):
    (tmp_path / "img").mkdir()
    shapes = {"round": (8.0, 8.0), "long": (16.0, 5.0), "mid": (11.0, 7.0)}
    rows = []
    for label, (sx, sy) in shapes.items():
        np.save(tmp_path / "img" / f"{label}.npy", gaussian((100, 120), 60, 50, sx, sy, amp=100.0))
        rows.append(f"img/{label}.npy,{label},0.1,-0.2")
    man = _manifest(tmp_path, rows)
    lib = tmp_path / "lib.yaml"
    code, out, err = cli(capsys, "library", "build", str(man), "--out", str(lib), "--features", kind,
                         "--json")
    assert code == 0, err
    return lib, json.loads(out)


def test_library_build_yaml_and_match_cli(tmp_path, capsys):
    lib_path, summary = _spot_library(tmp_path, capsys)
    assert summary["entries"] == 3
    data = yaml.safe_load(lib_path.read_text())
    assert data["version"] == 1 and data["features"] == "hu"
    assert all(len(e["features"]) == 7 and len(e["sha256"]) == 64 for e in data["entries"])
    # A rotated, shifted, brighter view of "long" is recognised as "long".
    q = gaussian((90, 140), 80, 40, 5.0, 16.0, amp=300.0)
    np.save(tmp_path / "q.npy", q)
    code, out, _ = cli(capsys, "match", str(tmp_path / "q.npy"), "--library", str(lib_path), "--json")
    assert code == 0
    d = json.loads(out)
    assert {"label", "distance", "runner_up", "az_deg", "el_deg", "unknown"} <= set(d)
    assert (d["label"], d["unknown"], d["az_deg"], d["el_deg"]) == ("long", False, 0.1, -0.2)
    assert d["runner_up"]["label"] == "mid" and d["runner_up"]["distance"] > d["distance"]


def test_match_reports_unknown_far_from_every_case(tmp_path, capsys):
    lib_path, _ = _spot_library(tmp_path, capsys)
    # A thin ring (radius 30 px, σ 4 px across) with dark background around it: no spot shape.
    yy, xx = np.mgrid[0:160, 0:160]
    ring = np.exp(-0.5 * ((np.hypot(xx - 80.0, yy - 80.0) - 30.0) / 4.0) ** 2)
    np.save(tmp_path / "ring.npy", np.clip(ring, 0, None))
    code, out, _ = cli(capsys, "match", str(tmp_path / "ring.npy"), "--library", str(lib_path), "--json")
    d = json.loads(out)
    assert code == 0 and d["unknown"] is True and d["label"] == "unknown" and d["az_deg"] is None


@pytest.mark.parametrize("mutate,message", [
    (lambda d: d.update(version=9), "version"),
    (lambda d: d.update(features="zernike"), "features"),
    (lambda d: d["entries"][0].update(features=[1, 2, 3]), r"entries\[0\].features"),
    (lambda d: d.update(entries=[]), "entries"),
])
def test_bad_library_file(tmp_path, capsys, mutate, message):
    lib_path, _ = _spot_library(tmp_path, capsys)
    data = yaml.safe_load(lib_path.read_text())
    mutate(data)
    lib_path.write_text(yaml.safe_dump(data))
    with pytest.raises(InputError, match=message):
        load_library(lib_path)
    code, _, err = cli(capsys, "match", str(tmp_path / "img" / "round.npy"), "--library", str(lib_path))
    assert code == 2 and len(err.strip().splitlines()) == 1


def test_library_build_bad_image_names_manifest_line(tmp_path, capsys):
    (tmp_path / "z.npy").write_bytes(b"not numpy")
    man = _manifest(tmp_path, ["z.npy,a,,"])
    out = tmp_path / "lib.yaml"
    code, _, err = cli(capsys, "library", "build", str(man), "--out", str(out))
    assert code == 2 and "m.csv:2" in err and not out.exists()


@pytest.mark.parametrize("kind", ["hu", "log-hu", "multi-hu", "multi-lobe-hu"])
def test_recognition_rate_on_default_errorset(errorset, tmp_path, capsys, kind):
    lib = tmp_path / f"lib-{kind}.yaml"
    code, _, err = cli(capsys, "library", "build", str(errorset / "library.csv"), "--out", str(lib),
                       "--features", kind)
    assert code == 0, err
    report = tmp_path / "report"
    code, out, err = cli(capsys, "report", "confusion", "--library", str(lib), "--test",
                         str(errorset / "test.csv"), "--out", str(report), "--json")
    assert code == 0, err
    d = json.loads(out)
    assert {"labels", "matrix", "recall", "fnr", "recognition_rate", "per_class"} <= set(d)
    assert len(d["labels"]) == 6 and d["n"] == 84
    assert d["recognition_rate"] >= 99.0, d["matrix"]
    assert d["recognition_rate"] == pytest.approx(100.0 * d["recall"])
    for name in ("confusion.csv", "confusion.md", "confusion.png", "report.json"):
        assert (report / name).stat().st_size > 0
    assert "| TP | FN | Recall | FNR |" in (report / "confusion.md").read_text()
    rows = list(csv.reader((report / "confusion.csv").open()))
    assert rows[0][1:] == [*d["labels"], "unknown"]


def test_errorset_manifests_and_determinism(errorset, tmp_path, capsys):
    lib_rows = read_manifest(errorset / "library.csv")
    test_rows = read_manifest(errorset / "test.csv")
    assert len(lib_rows) == 6 and len(test_rows) == 84
    assert len({r.label for r in lib_rows}) == 6
    assert all(r.image.is_file() for r in lib_rows + test_rows)
    # Same seed, same bytes: rerender the first two cases with 1 view and compare.
    again = tmp_path / "again"
    code, _, err = cli(capsys, "sim", "errorset", "--out", str(again), "--cases", "2", "--views", "1")
    assert code == 0, err
    for name in ("images/library-tracking-offset-00.npy", "images/test-wind-load-01.npy"):
        np.testing.assert_array_equal(np.load(again / name), np.load(errorset / name))


def test_errorset_bad_arguments(tmp_path, capsys):
    code, _, err = cli(capsys, "sim", "errorset", "--out", str(tmp_path / "x"), "--cases", "99")
    assert code == 2 and "--cases" in err


def _three_shapes() -> tuple[list[np.ndarray], list[str]]:
    shape = (100, 120)
    return ([gaussian(shape, 60, 50, 6, 6, amp=100.0), gaussian(shape, 60, 50, 14, 5, amp=100.0),
             gaussian(shape, 60, 50, 5, 15, amp=100.0)], ["round", "wide", "tall"])


def test_build_library_from_arrays_and_match_image_and_hu():
    from controller.imaging.beam import analyze
    from controller.recognition.library import build_library

    images, labels = _three_shapes()
    calls = []
    lib = build_library(images, labels, kind="log-hu", threshold=0.3, az_deg=[0.1, 0.2, 0.3],
                        progress=lambda done, total: calls.append((done, total)))
    assert lib.labels == labels and calls[-1] == (3, 3)
    assert lib.threshold == 0.3 and lib.entries[1].az_deg == 0.2
    lib.entries[1].correction = {"az_deg": 0.05, "el_deg": -0.02}
    # The same "wide" spot, moved and brighter: Hu moments ignore both.
    query = gaussian((100, 120), 40, 55, 14, 5, amp=300.0)
    by_image = lib.match_image(query)
    by_hu = lib.match_hu(analyze(query, threshold=0.3, background="auto").hu)
    assert by_image == by_hu
    assert (by_image.label, by_image.index, by_image.unknown) == ("wide", 1, False)
    assert (by_hu.label, by_hu.index) == ("wide", 1)
    assert by_image.correction_deg == (0.05, -0.02)
    assert by_image.runner_up in ("round", "tall") and by_image.runner_up_distance > by_image.distance
    assert lib.match_image(images[0]).correction_deg is None
    # The threshold reaches the analysis: a raw-Hu library sees the segmented region change.
    raw = build_library(images, labels, kind="hu", threshold=0.3)
    assert raw.match_image(query, threshold=0.7).distance > 2 * raw.match_image(query).distance


def test_build_library_names_the_image_without_a_beam():
    from controller.recognition.library import build_library

    images, labels = _three_shapes()
    images[2] = np.zeros((100, 120))
    with pytest.raises(InputError, match="c.npy: image is all zeros"):
        build_library(images, labels, names=["a.npy", "b.npy", "c.npy"])
    with pytest.raises(InputError, match="one label per image"):
        build_library(images[:2], labels)


def test_library_save_load_round_trip_keeps_matches(tmp_path):
    from controller.recognition.library import build_library
    from controller.recognition.library_io import save_library

    images, labels = _three_shapes()
    lib = build_library(images, labels, kind="log-hu")
    save_library(lib, tmp_path / "lib.yaml")
    back = load_library(tmp_path / "lib.yaml")
    for img in images:
        assert back.match_image(img).label == lib.match_image(img).label
    np.testing.assert_allclose(back.scale, lib.scale)


def test_beam_chain_match_is_the_library_match_one_type():
    from pathlib import Path

    from controller.calibration.cycle.beam_chain import BeamChain
    from controller.calibration.cycle.machine import Match
    from controller.config import load_config
    from controller.imaging.beam import analyze
    from controller.recognition.library import build_library

    cfg = load_config(Path(__file__).resolve().parents[2] / "configs" / "demo.yaml")
    images, labels = _three_shapes()
    lib = build_library(images, labels, kind="log-hu")
    lib.entries[2].correction = {"az_deg": -0.1, "el_deg": 0.03}
    from controller.calibration.cycle.observations import Observation

    hu = analyze(gaussian((100, 120), 50, 45, 5, 15, amp=50.0), threshold=lib.threshold).hu
    obs = Observation((50.0, 45.0), (0.0, 0.0, 0.0), hu, 50.0)
    m = BeamChain(cfg, library=lib).match(obs)
    want = lib.match_hu(hu)
    assert type(m) is Match and type(want) is Match  # one match type, from the library to the cycle
    assert m == want
    assert (m.label, m.correction_deg) == ("tall", (-0.1, 0.03))
    assert BeamChain(cfg).match(obs) is None
