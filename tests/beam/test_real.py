"""Real Jülich target photos (PAINT): the beam centroid lands close to UTIS.

UTIS (Kuhl et al., Solar Energy 2024) is projected into the 256x256 target image through the
target's four measured corners (beamkit.project_to_image). Measured offsets of our centroid
from UTIS, in px (1 px ~ 34 mm; `analyze(..., background=B)`, threshold 0.5):

    background         106293 137608 213508 216331 240796 99927 | mean median max
    auto, energy (default) 1.10 1.05   0.66   7.39   0.70  0.82 | 1.96  0.94  7.39
    energy, no step model 1.10 0.96   0.66   7.39   4.54  0.82 | 2.58  1.03  7.39
    auto, centroid=segment 2.5  1.0    2.0    7.0    7.2   2.0  |  3.6   2.2   7.2
    local (ring plane)    1.5    0.6    2.0    7.0    3.5   1.8 |  2.8   1.9   7.0
    fit   (spot model)    0.75   0.84   0.45   7.1    3.4   1.14 | 2.29  0.99  7.1

The default (controller/imaging/spot_centroid.py) is the full energy centroid in a symmetric
window over a quadratic surface (plus straight shadow steps, controller/imaging/step_edges.py)
fitted to a ring around the spot; its window size and the step thresholds were chosen on
real spots with a known centroid (UTIS main lobes laid onto empty-target photos, below), not on
these photos. "fit" (controller/imaging/spot_fit.py) fits an elliptical super-Gaussian and a quadratic
background by Cauchy-loss least squares over the ring neighbourhood of "local"; its centroid is
the model's centre. **The issue's goal (mean <= 1.5 px, max <= 3 px against UTIS) is not
reached**: mean 2.29, max 7.1. The two misses, from the images:

- 216331: UTIS's own flux estimate (216331-flux.png) holds a detached lobe in the top-right
  corner of the target (4.9 % of its energy) which moves UTIS's whole-flux centroid by 7.2 px.
  Against the centroid of UTIS's *main lobe* (the largest connected part of the flux image) our
  fit is 1.47 px off (local 0.55). Matching UTIS there would mean counting that corner
  brightness as beam, which no spot method here does.
- 240796: a shadow step runs under the lower-right tail of the spot; the background there is
  lower than any smooth surface through the ring predicts, so the tail is under-weighted and
  the centroid pulled up-left (3.4 px). A background with explicit step edges would be needed.

Against UTIS's main lobe the fit is 0.76 0.96 0.68 1.47 3.62 1.00 px (mean 1.42, max 3.62).

Not independent: the spot-model method was chosen after trying, on these six photos, a
full-energy centroid above the ring plane (k x noise footprint), gradient-domain step removal,
harmonic and masked-median backgrounds (docs/imaging.md); the loss scale was compared on them
(1, 2, 4 noise sigma: mean 2.19, 2.29, 2.42 px; 2 kept, the usual Cauchy constant, not the
photos' optimum), as was the quadratic background (plane: mean 2.40); the "local" ring
(0.25-0.75 radii) it starts from was itself chosen with these photos. The synthetic checks
with known centroids are tests/imaging/test_spot_fit.py.
Tolerances below: auto every sample < 9 px and median < 3 px; local every sample < 8 px,
mean < 3 px, median < 2.5 px, shadow-edge sample < 4.5 px; fit as in its test.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from beamkit import HELD_OUT, PAINT, main_lobe, paint_samples, project_to_image, real_spots

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


def test_spot_fit_centroid_close_to_utis_on_real_photos(towers):
    to_utis, to_main = {}, {}
    for sample in SAMPLES:
        r = analyze(read_image(PAINT / f"{sample}-cropped.png"), background="fit")
        c = np.array(r.centroid_px)
        to_utis[sample] = float(np.hypot(*(c - _utis_px(sample, towers))))
        to_main[sample] = float(np.hypot(*(c - main_lobe(sample)[1])))
    assert len(to_utis) == 6
    # The four photos without a shadow edge under the spot or a detached lobe: measured
    # 0.45-1.14 px (local: 0.55-2.02).
    for sample in ("106293", "137608", "213508", "99927"):
        assert to_utis[sample] < 1.5, to_utis
    assert float(np.mean(list(to_utis.values()))) < 2.6, to_utis  # measured 2.29 (local 2.75)
    assert to_utis["240796"] < 4.0, to_utis  # measured 3.42: the shadow step under the tail
    assert to_utis["216331"] < 8.0, to_utis  # measured 7.11: UTIS counts a detached lobe
    # Against UTIS's main lobe, 216331 agrees too (measured 1.47 px); 240796 stays at 3.6 px.
    assert to_main["216331"] < 2.0, to_main
    assert float(np.mean(list(to_main.values()))) < 1.6, to_main  # measured 1.42


def test_utis_flux_of_216331_has_a_detached_lobe():
    # Why no spot centroid reaches UTIS on 216331: UTIS's whole-flux centroid sits 7.2 px from the
    # centroid of its own main lobe; on the other samples the two agree within 0.25 px.
    gap = {}
    for sample in SAMPLES:
        flux = cv2.imread(str(PAINT / f"{sample}-flux.png"), cv2.IMREAD_GRAYSCALE).astype(float)
        yy, xx = np.indices(flux.shape)
        whole = np.array([(flux * xx).sum(), (flux * yy).sum()]) / flux.sum()
        gap[sample] = float(np.hypot(*(whole - main_lobe(sample)[1])))
    assert gap["216331"] > 5.0, gap
    assert max(v for k, v in gap.items() if k != "216331") < 0.5, gap


def test_default_energy_centroid_on_real_photos(towers):
    to_utis, to_main, second = {}, {}, {}
    for sample in SAMPLES:
        r = analyze(read_image(PAINT / f"{sample}-cropped.png"))
        c = np.array(r.centroid_px)
        to_utis[sample] = float(np.hypot(*(c - _utis_px(sample, towers))))
        to_main[sample] = float(np.hypot(*(c - main_lobe(sample)[1])))
        second[sample] = r.second_spot_px
        assert r.clipped == ()
    print(f"\nPAINT, default centroid to UTIS px: {to_utis}; mean {np.mean(list(to_utis.values())):.2f}")
    for sample in ("106293", "137608", "213508", "99927"):  # measured 0.66-1.10
        assert to_utis[sample] < 1.5, to_utis
    assert float(np.mean(list(to_utis.values()))) < 2.1, to_utis  # measured 1.96 (old default 3.60)
    # 240796: the shadow step under the tail is modelled (measured 0.70; 4.54 without the step).
    assert to_utis["240796"] < 1.2, to_utis
    # 216331: UTIS's whole-flux centroid holds the detached corner lobe; the default reports it as
    # a second spot instead of averaging it in, and lands on UTIS's main lobe.
    assert second["216331"] is not None and second["216331"][0] > 200 and second["216331"][1] < 40
    assert to_main["216331"] < 1.5, to_main
    assert all(v is None for k, v in second.items() if k != "216331"), second
    assert float(np.mean(list(to_main.values()))) < 1.0, to_main  # measured 0.84


def test_the_shadow_steps_of_240796_and_137608_are_found_and_only_there():
    from controller.imaging.presence import detect_beam
    from controller.imaging.spot_centroid import spot_centroid

    steps = {}
    for sample in SAMPLES:
        img = read_image(PAINT / f"{sample}-cropped.png")
        steps[sample] = spot_centroid(img, detect_beam(img)).steps
    assert all(not v for k, v in steps.items() if k not in ("240796", "137608")), steps
    (st,) = steps["240796"]
    # The edge runs from about (0, 160) to (230, 117) px, darker below: normal ≈ 78° from +x
    # (measured 77.9°, 14.2 counts).
    angle = float(np.degrees(np.arctan2(st.ny, st.nx)))
    assert 70.0 < angle < 85.0 and -20.0 < st.height < -8.0, st
    # 137608: a weaker diagonal edge above the spot, from about (0, 135) to (235, 5) px, darker
    # above it (measured normal 59.0°, 6.4 counts).
    (st,) = steps["137608"]
    angle = float(np.degrees(np.arctan2(st.ny, st.nx)))
    assert 52.0 < angle < 66.0 and 3.0 < st.height < 10.0, st


def test_real_spots_on_held_out_empty_targets_centroid_with_known_truth():
    """Each PAINT spot (UTIS's main lobe, at the brightness it has in its own photo) laid onto
    the 20 held-out empty-target photos: the true centroid is known exactly, the background is
    real. Measured (mean / p95 / max px): default 0.72 / 1.77 / 2.16; centroid="segment" (old
    default) 1.39 / 3.01 / 3.78; fit 1.04 / 2.69 / 3.27; local 1.38 / 2.77 / 3.61."""
    errs = {"energy": [], "segment": []}
    for spot, truth in real_spots():
        for p in HELD_OUT:
            img = read_image(p).astype(float) + spot
            for mode in errs:
                c = np.array(analyze(img, centroid=mode).centroid_px)
                errs[mode].append(float(np.hypot(*(c - truth))))
    e, old = np.array(errs["energy"]), np.array(errs["segment"])
    print(f"\nreal spots on held-out empty targets: default mean {e.mean():.2f} max {e.max():.2f}; "
          f"old default mean {old.mean():.2f} max {old.max():.2f}")
    assert e.mean() < 1.0 and e.max() < 2.6, e
    assert e.mean() < 0.7 * old.mean()


def test_centroid_error_on_real_backgrounds_grows_as_the_spot_gets_fainter():
    """The composites above at 0.5, 1 and 2 times each spot's own brightness (docs/imaging.md,
    "Brightness"). Measured mean / p95 / max px: 1.61 / 3.71 / 5.43, 0.71 / 1.71 / 2.17,
    0.49 / 1.19 / 1.55."""
    held_out = [read_image(p).astype(float) for p in HELD_OUT]
    spots = real_spots()
    mean = {}
    for scale in (0.5, 1.0, 2.0):
        e = np.array([np.hypot(*(np.array(analyze(bg + scale * spot).centroid_px) - truth))
                      for spot, truth in spots for bg in held_out])
        mean[scale] = float(e.mean())
        print(f"\nbrightness x{scale}: mean {e.mean():.2f} p95 {np.percentile(e, 95):.2f} "
              f"max {e.max():.2f} px")
    assert mean[2.0] < mean[1.0] < mean[0.5] < 2.0, mean
