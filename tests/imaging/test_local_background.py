"""The ring ("local") background of controller.imaging.background on synthetic spots: vignetting
(a bowl-shaped background, 20 counts under a 100-count spot) that one plane over the view
cannot follow; and the median the background statistics take."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.imaging.background import estimate_local_background, median
from controller.imaging.beam import analyze


def _vignetted(cx: float, cy: float, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:256, 0:256].astype(float)
    bowl = 20.0 * ((xx - 128) ** 2 + (yy - 128) ** 2) / 128**2
    spot = 100.0 * np.exp(-0.5 * (((xx - cx) / 12) ** 2 + ((yy - cy) / 8) ** 2))
    return 50.0 + bowl + spot + rng.normal(0.0, 2.0, (256, 256))


def _err(img: np.ndarray, cx: float, cy: float, **kw) -> float:
    return float(np.hypot(*(np.array(analyze(img, **kw).centroid_px) - (cx, cy))))


@pytest.mark.parametrize("cx, cy", [(70.0, 80.0), (180.0, 150.0)])
def test_local_background_removes_the_vignetting_bias(cx, cy):
    # Measured over seeds 0-2: plane 0.34-0.40 px; local 0.03-0.16 px (mean 0.09 and 0.04);
    # the default energy centroid over its surface around the spot 0.02-0.12 px.
    imgs = [_vignetted(cx, cy, seed) for seed in range(3)]
    plane = [_err(img, cx, cy, centroid="segment") for img in imgs]
    local = [_err(img, cx, cy, background="local") for img in imgs]
    energy = [_err(img, cx, cy) for img in imgs]
    assert min(plane) > 0.3, plane
    assert max(local) < 0.2 and np.mean(local) < 0.12, local
    assert max(energy) < 0.2, energy


def test_local_neighbourhood_surrounds_the_spot_only():
    img = _vignetted(180.0, 150.0)
    bg, near = estimate_local_background(img)
    rows, cols = np.nonzero(near)
    assert near[150, 180] and not near[20, 20]
    assert 100 < cols.min() < 180 < cols.max() < 256 and 80 < rows.min() < 150 < rows.max()
    # Under the spot the ring plane is the bowl within 2 noise sigma (measured 3.9 counts: the
    # bowl curves by about that much across the ring).
    bowl = 50.0 + 20.0 * ((180 - 128) ** 2 + (150 - 128) ** 2) / 128**2
    assert abs(bg.evaluate((256, 256))[150, 180] - bowl) < 4.5


def test_local_respects_the_target_mask():
    img = _vignetted(70.0, 80.0)
    mask = np.zeros(img.shape, bool)
    mask[:, :128] = True
    _, near = estimate_local_background(img, mask)
    assert not near[:, 128:].any()
    assert _err(img, 70.0, 80.0, background="local", mask=mask.astype(np.uint8)) < 0.2  # measured 0.17


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-1e6, 1e6, allow_nan=False, width=32), max_size=64),
       st.sampled_from([np.float32, np.float64]))
def test_median_is_numpys_median(values, dtype):
    # The background's own median (one partial sort) must be numpy's, for odd and even counts and
    # both image precisions: the presence statistic and the planes are compared with thresholds.
    a = np.asarray(values, dtype)
    if not a.size:
        assert np.isnan(median(a))
    else:
        assert median(a) == float(np.median(a))
