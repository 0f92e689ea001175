"""Real Jülich target photos (PAINT): the beam centroid lands close to UTIS.

UTIS (Kuhl et al., Solar Energy 2024) is projected into the 256x256 target image through the
target's four measured corners (beamkit.project_to_image). Measured offsets of our centroid
(threshold 0.5) from UTIS, in px (1 px ~ 34 mm):

    background       106293 137608 213508 216331 240796 99927 | mean median max
    auto  (plane)       2.5    1.0    2.0    7.0    7.2   2.0 |  3.6   2.2   7.2
    local (ring plane)  1.5    0.6    2.0    7.0    3.5   1.8 |  2.8   1.9   7.0

"local" refits the background plane to a ring around the spot (analysis restricted to that
neighbourhood), which follows the shadow edge next to the spot of 240796 better than one
plane over the view; the step itself still biases it. 216331 is the faintest spot (~40 counts
over a 177-count target, flat-topped, so the half-peak region is small and noise-shaped);
there the two independent methods in the record, HeliOS and UTIS, differ by 13.2 px (ours:
7.0 px from UTIS, 11.6 px from HeliOS). The ring size (0.25-0.75 footprint radii) was chosen
from three settings on synthetic spots *and these six photos* (docs/imaging.md), so this is
not an independent test. The issue's goal (mean <= 1.5 px, max <= 3 px) is not
reached. Tolerances: auto every sample < 9 px and median < 3 px; local every sample < 8 px,
mean < 3 px, median < 2.5 px and the shadow-edge sample < 4.5 px.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from beamkit import PAINT, paint_samples, project_to_image

from controller.imaging.beam import analyze
from controller.io.images import read_image

SAMPLES = paint_samples()


def _record(sample: str) -> dict:
    return json.loads((PAINT / f"{sample}-calibration-properties.json").read_text())


def _utis_px(sample: str, towers: dict) -> np.ndarray:
    rec = _record(sample)
    return project_to_image(rec["focal_spot"]["UTIS"], towers[rec["target_name"]])


@pytest.mark.parametrize("sample", SAMPLES)
def test_projection_matches_flux_image_centroid(sample, towers):
    # Check of the projection itself: UTIS lies within ~0.6 px of the *-flux.png centroid (README).
    flux = cv2.imread(str(PAINT / f"{sample}-flux.png"), cv2.IMREAD_GRAYSCALE).astype(float)
    yy, xx = np.indices(flux.shape)
    c = np.array([(flux * xx).sum(), (flux * yy).sum()]) / flux.sum()
    assert np.hypot(*(c - _utis_px(sample, towers))) < 0.75


def test_centroid_close_to_utis_on_real_photos(towers):
    offsets = {}
    for sample in SAMPLES:
        r = analyze(read_image(PAINT / f"{sample}-cropped.png"))
        offsets[sample] = float(np.hypot(*(np.array(r.centroid_px) - _utis_px(sample, towers))))
    assert len(offsets) == 6
    assert max(offsets.values()) < 9.0, offsets
    assert float(np.median(list(offsets.values()))) < 3.0, offsets


def test_local_background_centroid_close_to_utis_on_real_photos(towers):
    offsets = {}
    for sample in SAMPLES:
        r = analyze(read_image(PAINT / f"{sample}-cropped.png"), background="local")
        offsets[sample] = float(np.hypot(*(np.array(r.centroid_px) - _utis_px(sample, towers))))
    assert len(offsets) == 6
    assert max(offsets.values()) < 8.0, offsets
    assert float(np.mean(list(offsets.values()))) < 3.0, offsets
    assert float(np.median(list(offsets.values()))) < 2.5, offsets
    # The shadow-edge sample is where the ring plane helps: 7.2 px with the whole-view plane.
    assert offsets["240796"] < 4.5, offsets
