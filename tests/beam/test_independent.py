"""Recognition that generalises beyond the project's own optics (issue #14).

The lobe row of ``multi-lobe-hu`` (:mod:`controller.recognition.lobes`) on synthetic spots, and
the CLI default on the two independent renderers of ``benchmarks/`` (``independent_spots``: spot
size zooms; ``facet_spots``: 3 x 3 facets, spot size blurs), rendered here at a seed that played
no part in choosing the defaults (they were chosen on seeds 1-3), with magnitude 0.5-1.5 and
spot size x0.7-1.4 varying in the test views and three magnitudes per case in the library.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from beamkit import cli

from controller.imaging.beam import analyze
from controller.recognition.lobes import lobes_hu

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import facet_spots  # noqa: E402
import independent_spots  # noqa: E402

SEED = 7  # not one of the design seeds 1-3


def _gauss(shape, x, y, sigma, amp):
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    return amp * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * sigma**2))


def _two_lobes(angle_deg: float = 0.0) -> np.ndarray:
    """A bright lobe and a detached one at 40 % of its peak, on a small pedestal (x = column)."""
    img = _gauss((120, 120), 42, 60, 6.0, 1000.0) + _gauss((120, 120), 80, 60, 5.0, 400.0) + 10.0
    if angle_deg:
        m = cv2.getRotationMatrix2D((59.5, 59.5), angle_deg, 1.0)
        img = cv2.warpAffine(img.astype(np.float32), m, (120, 120), flags=cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_REPLICATE)
    return img.astype(np.float32)


def _unit_mean_hu(signal: np.ndarray, region: np.ndarray) -> np.ndarray:
    w = np.where(region, signal, 0.0).astype(np.float64)
    w *= np.count_nonzero(region) / w.sum()
    return cv2.HuMoments(cv2.moments(w)).ravel()


def test_lobes_hu_counts_a_detached_lobe_that_the_largest_region_drops():
    img = _two_lobes()
    largest = analyze(img, threshold=0.1).hu
    lobes = lobes_hu(img, 0.1)
    # Two lobes 38 px apart are far more elongated than the round main lobe alone.
    assert lobes[0] > 3 * largest[0] and lobes[1] > 100 * largest[1]
    # Independent check: Hu of the union of both regions (the pedestal is flat: subtract it),
    # via OpenCV, at unit mean over the union.
    signal = img - 10.0
    smooth = cv2.GaussianBlur(signal, (5, 5), 1.0, borderType=cv2.BORDER_REPLICATE)
    region = smooth > 0.1 * smooth.max()
    np.testing.assert_allclose(lobes[:4], _unit_mean_hu(signal, region)[:4], rtol=0.02)


def test_lobes_hu_ignores_a_hot_pixel_and_the_rotation():
    img = _two_lobes()
    hot = img.copy()
    hot[10, 10] += 600.0  # above 0.1 of the peak after smoothing, but far below 1 % of the energy
    np.testing.assert_allclose(lobes_hu(hot, 0.1)[:2], lobes_hu(img, 0.1)[:2], rtol=1e-3)
    np.testing.assert_allclose(lobes_hu(np.rot90(img).copy(), 0.1)[:4], lobes_hu(img, 0.1)[:4], rtol=1e-6)
    # A 35 deg turn resamples the image (bilinear): phi_1 and the elongation sqrt(phi_2) within 2 %.
    turned, straight = lobes_hu(_two_lobes(35.0), 0.1), lobes_hu(img, 0.1)
    np.testing.assert_allclose([turned[0], np.sqrt(turned[1])], [straight[0], np.sqrt(straight[1])],
                               rtol=0.02)


def test_lobes_hu_rejects_an_empty_frame():
    from controller.errors import InputError

    with pytest.raises(InputError, match="no beam"):
        lobes_hu(np.full((50, 50), 7.0, dtype=np.float32), 0.1)


@pytest.fixture(scope="module", params=["independent_spots", "facet_spots"])
def independent_set(request, tmp_path_factory):
    module = {"independent_spots": independent_spots, "facet_spots": facet_spots}[request.param]
    out = tmp_path_factory.mktemp(request.param)
    module.write_set(out, seed=SEED, views=6)
    return request.param, out


def _score(capsys, out: Path, *features: str) -> dict:
    lib = out / f"lib{'-'.join(features)}.yaml"
    code, _, err = cli(capsys, "library", "build", str(out / "library.csv"), "--out", str(lib), *features,
                       "--json")
    assert code == 0, err
    code, stdout, err = cli(capsys, "report", "confusion", "--library", str(lib), "--test",
                            str(out / "test.csv"), "--out", str(out / f"rep{'-'.join(features)}"), "--json")
    assert code == 0, err
    return json.loads(stdout)


# Bars below the rates measured on the design seeds 1-3 (24 views per case: independent_spots
# 95.8-97.9 %, facet_spots 86.1-93.1 %; here, 6 views per case: 97.2 and 94.4 %), leaving room
# for the smaller set's sampling spread (one view is 2.8 points).
BAR = {"independent_spots": 92.0, "facet_spots": 80.0}


def test_default_library_generalises_to_both_independent_renderers(independent_set, capsys):
    name, out = independent_set
    default = _score(capsys, out)
    assert default["features"] == "multi-lobe-hu"
    assert default["recognition_rate"] >= BAR[name], default["per_class"]
    assert default["unknown_rate"] <= 0.03  # the bar for unknowns
    # Widening the views no case claims pays on both (measured +5.6 points each here).
    plain = _score(capsys, out, "--widen", "no")
    assert default["recognition_rate"] > plain["recognition_rate"]
    assert plain["widened"] == 0 < default["widened"]
    # The paper's raw Hu distance is far below on the same set (measured 44-62 % on seeds 1-3).
    paper = _score(capsys, out, "--features", "hu", "--whiten", "no")
    assert default["recognition_rate"] >= paper["recognition_rate"] + 15
