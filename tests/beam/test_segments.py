"""Matching along segments between neighbouring magnitudes of a case (interpolated library)."""

from __future__ import annotations

import numpy as np
import pytest

from controller.recognition.library import Entry, Library
from controller.recognition.matching import Matcher
from controller.recognition.segments import magnitude_segments


def _library(with_magnitudes: bool = True) -> Library:
    """Case 'a' at magnitudes 0.5, 1, 1.5 along feature 1 (listed out of order); 'b' off to the side."""
    entries = [Entry("a", np.eye(7)[0] * 0.1 * m, az_deg=0.2 * m, el_deg=-0.1 * m,
                     params={"magnitude": m} if with_magnitudes else None) for m in (1.5, 0.5, 1.0)]
    entries.append(Entry("b", np.eye(7)[1] * 0.065 + np.eye(7)[0] * 0.125, az_deg=0.0, el_deg=0.0))
    for e in entries:
        e.unknown_distance = 0.2
    return Library(features="hu", threshold=0.5, entries=entries)


@pytest.mark.parametrize("with_magnitudes", [True, False])
def test_segments_join_neighbouring_magnitudes_in_order(with_magnitudes):
    lib = _library(with_magnitudes)
    pairs = {tuple(p) for p in magnitude_segments(lib.entries, lib.transform(lib.matrix()))}
    # 0.5-1.0 (entries 1, 2) and 1.0-1.5 (entries 2, 0); never 0.5-1.5, never across cases.
    assert pairs == {(1, 2), (0, 2)}


def test_a_view_between_two_magnitudes_matches_the_interpolated_entry():
    lib = _library()
    q = np.eye(7)[0] * 0.125 + np.eye(7)[1] * 0.03  # half-way between m = 1 and 1.5, off the line
    m = lib.match_hu(q)
    # Distance to the segment (0.03), not to its ends (hypot(0.025, 0.03) = 0.039); b lies
    # 0.035 from q, so without the segment b would win.
    assert (m.label, m.distance) == ("a", pytest.approx(0.03))
    assert m.magnitude == pytest.approx(1.25) and m.error_deg == pytest.approx((0.25, -0.125))
    assert m.runner_up == "b" and m.runner_up_distance == pytest.approx(0.035)
    lib.interpolate, lib._cache = False, None
    assert lib.match_hu(q).label == "b"


def test_matcher_rejects_a_segment_across_cases():
    with pytest.raises(ValueError, match="same label"):
        Matcher(np.eye(3), ["a", "a", "b"], segments=np.array([[0, 2]]))


def test_segment_match_agrees_with_brute_force_on_random_libraries():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(60, 5))
    labels = [f"c{i // 3}" for i in range(60)]
    seg = np.array([(i, i + 1) for i in range(0, 60, 3)] + [(i + 1, i + 2) for i in range(0, 60, 3)])
    m = Matcher(x, labels, segments=seg)
    for q in rng.normal(size=(20, 5)):
        best = np.inf
        for a, b in seg:
            d = x[b] - x[a]
            t = np.clip((q - x[a]) @ d / (d @ d), 0, 1)
            best = min(best, np.linalg.norm(q - x[a] - t * d))
        assert m.match(q).distance == pytest.approx(best, rel=1e-9)
