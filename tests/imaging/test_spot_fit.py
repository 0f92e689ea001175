"""The spot-model centroid (``analyze(..., background="fit")``, controller/imaging/spot_fit.py)
where the truth is known: synthetic 256x256 target photos with a spot whose shape is *not* the
model's (an elliptical uniform disc, 80 x 32 px at 35 deg, blurred by a Gaussian of 6 px: flat
top, soft edge), on the backgrounds that defeat a plane over the view. The true centroid is the
intensity centroid of the noise-free spot itself. Noise 4 counts (Gaussian), spot centre drawn
in [100, 156]^2, three seeds per case.

Measured max / mean error over the seeds, px (auto / local / fit):

    faint (40 counts over 177, flat background)          0.19/0.17  0.16/0.10  0.10/0.07
    faint, vignetted (target 30 counts darker at r=128)  1.37/0.99  0.29/0.16  0.13/0.07
    shadow step of 20 counts, 30 px beside the spot     0.21/0.19  0.10/0.05  0.03/0.02
    the same step 10 px beside the spot                 0.28/0.24  0.51/0.49  0.67/0.64
    the same step 8 px inside the spot's edge           1.41/1.40  0.94/0.91  0.98/0.98

(bright spot, 100 counts, for the steps). The spot model wins where the background is smooth;
a shadow step close to the spot biases it more than the plane over the view, and one under the
spot's edge as much as the ring plane (about 1 px here; 3.4 px on the real photo 240796), which
the tests below record rather than hide.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from controller.errors import InputError
from controller.imaging.background import Background
from controller.imaging.beam import analyze
from controller.imaging.spot_fit import SpotGuess, fit_spot

SHAPE = (256, 256)
ANGLE = np.radians(35.0)


def _rotated(cx: float, cy: float) -> tuple[np.ndarray, np.ndarray]:
    yy, xx = np.mgrid[0:SHAPE[0], 0:SHAPE[1]].astype(float)
    u = (xx - cx) * np.cos(ANGLE) + (yy - cy) * np.sin(ANGLE)
    v = -(xx - cx) * np.sin(ANGLE) + (yy - cy) * np.cos(ANGLE)
    return u, v


def _spot(cx: float, cy: float, amp: float) -> np.ndarray:
    """Uniform ellipse (semi-axes 40 x 16 px, a 1-px linear edge) blurred by sigma 6 px."""
    u, v = _rotated(cx, cy)
    disc = np.clip((1.0 - np.hypot(u / 40.0, v / 16.0)) * 16.0 + 0.5, 0.0, 1.0)
    return amp * cv2.GaussianBlur(disc, (0, 0), 6.0)


def _scene(seed: int, kind: str, amp: float = 40.0, gap: float = 30.0) -> tuple[np.ndarray, np.ndarray]:
    """(image, true centroid (x, y)) for one seed."""
    rng = np.random.default_rng(seed)
    cx, cy = rng.uniform(100.0, 156.0, 2)
    spot = _spot(cx, cy, amp)
    yy, xx = np.indices(SHAPE)
    truth = np.array([(spot * xx).sum(), (spot * yy).sum()]) / spot.sum()
    if kind == "flat":
        bg = np.full(SHAPE, 177.0)
    elif kind == "vignetted":
        bg = 190.0 - 30.0 * ((xx - 128.0) ** 2 + (yy - 128.0) ** 2) / 128.0**2
    else:  # a straight shadow edge along the major axis, `gap` px beyond the minor semi-axis
        _, v = _rotated(cx, cy)
        bg = 160.0 + 20.0 * (v > 16.0 + gap)
    return bg + spot + rng.normal(0.0, 4.0, SHAPE), truth


def _errors(background: str, centroid: str = "energy", **scene) -> list[float]:
    out = []
    for seed in range(3):
        img, truth = _scene(seed, **scene)
        c = analyze(img, background=background, centroid=centroid).centroid_px
        out.append(float(np.hypot(*(np.array(c) - truth))))
    return out


def test_faint_flat_topped_spot():
    fit = _errors("fit", kind="flat")
    assert max(fit) < 0.2 and np.mean(fit) < 0.1, fit  # measured 0.10 / 0.07
    assert np.mean(fit) < np.mean(_errors("local", kind="flat")), fit  # local 0.16 / 0.10


def test_faint_spot_on_a_vignetted_target():
    fit = _errors("fit", kind="vignetted")
    assert max(fit) < 0.25 and np.mean(fit) < 0.12, fit  # measured 0.13 / 0.07
    # The thresholded centroid above the plane over the view: 0.37-1.37.
    assert max(_errors("auto", centroid="segment", kind="vignetted")) > 1.0
    # The default energy centroid over the surface fitted around the spot: 0.08-0.53 (its
    # window, 4 footprint σ, takes in more of the bowl than the fit's model does).
    assert max(_errors("auto", kind="vignetted")) < 0.6


def test_shadow_step_beside_the_spot():
    fit = _errors("fit", kind="step", amp=100.0, gap=30.0)
    assert max(fit) < 0.1, fit  # measured 0.03
    assert max(_errors("local", kind="step", amp=100.0, gap=30.0)) > max(fit)


@pytest.mark.parametrize("gap, limit", [(10.0, 0.9), (-8.0, 1.3)])
def test_shadow_step_close_to_or_under_the_spot_biases_it(gap, limit):
    # The known weakness (see the module docstring): measured 0.62-0.67 px (10 px beside) and
    # 0.97-0.98 px (under the edge); bounded here so that a regression shows, and well above the
    # 0.1 px of the clean cases: a bias of the method, not noise.
    fit = _errors("fit", kind="step", amp=100.0, gap=gap)
    assert max(fit) < limit, fit
    assert min(fit) > 0.3, fit


def test_spot_fit_reports_the_model():
    img, truth = _scene(0, kind="flat", amp=100.0)
    r = analyze(img, background="fit")
    f = r.spot_fit
    assert f is not None and (f.x, f.y) == r.centroid_px
    assert abs(f.angle_deg - 35.0) < 2.0
    assert f.sigma_major_px > 2.0 * f.sigma_minor_px
    assert f.exponent > 1.0  # flat-topped
    assert abs(f.residual_rms - 4.0) < 1.0  # the noise that was added
    assert 90.0 < f.amplitude < 110.0
    # The background surface under the spot (outside the neighbourhood it is an extrapolation):
    # measured 181.0 - the super-Gaussian's skirt is not the blurred disc's, and the quadratic
    # takes up the difference (amplitude 94 instead of 100); the centre is not affected.
    assert abs(float(f.background.evaluate(SHAPE)[int(truth[1]), int(truth[0])]) - 177.0) < 6.0
    assert r.as_dict()["spot_fit"]["centre_px"] == [f.x, f.y]
    assert "spot_fit" not in analyze(img).as_dict()


def test_spot_fit_refuses_too_small_a_region():
    img, _ = _scene(0, kind="flat")
    region = np.zeros(SHAPE, bool)
    region[10:13, 10:13] = True
    guess = SpotGuess(x=11.0, y=11.0, peak=40.0, sigma_major_px=5.0, sigma_minor_px=3.0, angle_deg=0.0)
    with pytest.raises(InputError, match="spot fit"):
        fit_spot(img, region, guess, Background(level=177.0, noise=4.0))


def test_spot_fit_refuses_a_spot_that_is_not_there():
    # Pure noise: whatever the guess, the fit must not return a centre it cannot support.
    rng = np.random.default_rng(3)
    img = 177.0 + rng.normal(0.0, 4.0, SHAPE)
    guess = SpotGuess(x=128.0, y=128.0, peak=10.0, sigma_major_px=30.0, sigma_minor_px=12.0, angle_deg=35.0)
    with pytest.raises(InputError, match="spot fit failed"):
        fit_spot(img, np.ones(SHAPE, bool), guess, Background(level=177.0, noise=4.0))


def test_cli_beam_background_fit_and_local(tmp_path, capsys):
    import json

    from controller.cli import main

    img, truth = _scene(1, kind="vignetted")
    path = tmp_path / "spot.npy"
    np.save(path, img.astype(np.float32))
    assert main(["beam", str(path), "--background", "fit", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert np.hypot(*(np.array(out["centroid_px"]) - truth)) < 0.25
    assert out["spot_fit"]["centre_px"] == out["centroid_px"]
    assert {"peak", "total", "pixels", "hu", "ellipse", "d90_px"} <= set(out)  # the existing keys stay
    # "local" is a method, not a null-image file name.
    assert main(["beam", str(path), "--background", "local", "--json"]) == 0
    assert "spot_fit" not in json.loads(capsys.readouterr().out)
