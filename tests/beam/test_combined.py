"""Combined errors, two mechanisms at once, as cases of their own (issue #14, deliver item 1)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from beamkit import cli

from controller.recognition.confusion import mechanism_recall, mechanisms
from simplant.errorset import CASES, beam_error_deg, scene_from_config, shape_pairs

BY = {c.label: c for c in CASES}


def test_a_pair_adds_both_mechanisms_and_scales_as_one():
    a, b = BY["wind-load"], BY["gear-backlash"]
    ab = a.combined(b)
    assert ab.label == "wind-load+gear-backlash" and ab.has_shape()
    assert ab.params.el_offset == a.params.el_offset and ab.params.az_offset == b.params.az_offset
    assert ab.rock_az_rad == b.rock_az_rad
    x, y = np.array([0.5, -1.0]), np.array([1.0, 0.3])
    np.testing.assert_allclose(ab.deformation(x, y), a.deformation(x, y))  # backlash has no slopes
    sag_split = BY["gravity-sag"].combined(BY["facet-split"])
    want = np.add(BY["gravity-sag"].deformation(x, y), BY["facet-split"].deformation(x, y))
    np.testing.assert_allclose(sag_split.deformation(x, y), want)
    half = sag_split.scaled(0.5)
    np.testing.assert_allclose(half.deformation(x, y), 0.5 * want)
    assert half.params.el_offset == pytest.approx(0.5 * sag_split.params.el_offset)


def test_shape_pairs_leave_out_the_pure_pointing_case():
    pairs = shape_pairs(CASES[:6])
    assert len(pairs) == 10  # the five shape cases, two at a time
    assert all("tracking-offset" not in p.label for p in pairs)
    assert not BY["tracking-offset"].has_shape() and all(c.has_shape() for c in CASES[1:])


def test_a_pairs_beam_error_is_the_sum_of_its_parts():
    from controller.config import load_config

    config = Path(__file__).resolve().parents[2] / "configs" / "demo.yaml"
    scene = scene_from_config(load_config(config), "H09")
    a, b = BY["tracking-offset"], BY["gravity-sag"]
    both = np.array(beam_error_deg(scene, a.combined(b)))
    # Small angles (mrad): the two pointing errors add to well under 1 % of their size.
    np.testing.assert_allclose(both, np.add(beam_error_deg(scene, a), beam_error_deg(scene, b)),
                               atol=0.01 * np.abs(both).max())


def test_mechanism_recall_counts_each_mechanism_of_a_pair():
    true = ["a+b", "a+b", "a", "b", "a+b"]
    pred = ["a+b", "a", "a", "unknown", "c+b"]
    r = mechanism_recall(true, pred)
    assert r["a"] == {"n": 4, "found": 3, "exact": 2, "recall": 0.75}
    assert r["b"] == {"n": 4, "found": 2, "exact": 1, "recall": 0.5}
    assert mechanisms("unknown") == () and mechanisms("a+b") == ("a", "b")


def test_sim_errorset_combined_and_report_by_mechanism(tmp_path, capsys):
    code, out, err = cli(capsys, "sim", "errorset", "--out", str(tmp_path / "es"), "--cases", "3",
                         "--views", "2", "--combined", "--json")
    assert code == 0, err
    d = json.loads(out)
    # tracking-offset, wind-load, gear-backlash and the one pair of the two shape cases.
    assert d["labels"] == ["tracking-offset", "wind-load", "gear-backlash", "wind-load+gear-backlash"]
    lib = str(tmp_path / "lib.yaml")
    assert cli(capsys, "library", "build", d["library_manifest"], "--out", lib, "--json")[0] == 0
    code, out, err = cli(capsys, "report", "confusion", "--library", lib, "--test", d["test_manifest"],
                         "--out", str(tmp_path / "rep"), "--json")
    assert code == 0, err
    rep = json.loads(out)
    assert set(rep["mechanisms"]) == {"tracking-offset", "wind-load", "gear-backlash"}
    assert rep["mechanisms"]["wind-load"]["n"] == 4  # its own 2 views and the pair's 2
    assert "By mechanism" in (tmp_path / "rep" / "confusion.md").read_text()
