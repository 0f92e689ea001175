"""Fiducials in a camera image, a camera's nominal pose, and a saturation-safe rectification.

Pure functions (numpy in, numpy out) for the registration step
(:mod:`controller.calibration.cycle.registration_step`); the camera model and its fit are in
:mod:`controller.imaging.registration`.

Conventions: ENU metres; pixel (u, v) = (column, row), (0, 0) the centre of the top-left pixel;
camera coordinates X_c = R · X_enu + t with +Z_c the line of sight, +X_c image right (columns),
+Y_c image down (rows), as OpenCV.
"""

from __future__ import annotations

import cv2
import numpy as np

from controller.errors import InputError
from controller.imaging.registration import remap

_UP = np.array([0.0, 0.0, 1.0])
# Half-size (px) of the box a fiducial's centroid is taken over: a lit marker a few cm across
# at ~100 m is a blob of σ ≈ 2 px; ±7 px holds > 99 % of its light and little background.
CENTROID_HALF_PX = 7


def look_at_pose(position_enu, look_at_enu, roll_rad: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(rvec, tvec) of a camera at ``position_enu`` whose optical axis points at ``look_at_enu``,
    image rows running down (image x level), rotated by ``roll_rad`` about the line of sight.

    R's rows are the camera axes in ENU: z = unit(look_at − C), x = unit(z × up) rotated by the
    roll, y = z × x (down); t = −R C."""
    c = np.asarray(position_enu, float).reshape(3)
    z = np.asarray(look_at_enu, float).reshape(3) - c
    if not np.linalg.norm(z) > 0:
        raise InputError("camera pose: the look-at point is the camera position")
    z = z / np.linalg.norm(z)
    x = np.cross(z, _UP)
    if np.linalg.norm(x) < 1e-9:
        raise InputError("camera pose: a camera looking straight up or down needs another up axis")
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    cr, sr = np.cos(roll_rad), np.sin(roll_rad)
    r = np.vstack([cr * x + sr * y, -sr * x + cr * y, z])
    return cv2.Rodrigues(r)[0].reshape(3), -r @ c


def detect_fiducials(image: np.ndarray, predicted_px: np.ndarray, radius_px: float,
                     min_snr: float = 10.0) -> np.ndarray:
    """Pixel (u, v) of each lit fiducial in ``image`` (a lamps-on minus lamps-off difference,
    float), looked for within ``radius_px`` of its predicted pixel; NaN rows where none stands
    ``min_snr`` noise σ above the background.

    Per fiducial: the brightest pixel in the search disc, then the intensity centroid
    Σ w·(u, v) / Σ w over a (2·CENTROID_HALF_PX + 1)² box around it, w = max(I − b, 0) with b the
    box border's median (the residual background). The noise σ is 1.4826 × the median absolute
    deviation of the whole image (robust: fiducials are a tiny fraction of it)."""
    img = np.asarray(image, dtype=np.float64)
    if img.ndim != 2:
        raise InputError(f"fiducial detection expects a 2-D image, got shape {img.shape}")
    pred = np.asarray(predicted_px, float).reshape(-1, 2)
    rows, cols = img.shape
    med = float(np.median(img))
    sigma = max(1.4826 * float(np.median(np.abs(img - med))), 1e-12)
    out = np.full((len(pred), 2), np.nan)
    h = CENTROID_HALF_PX
    r = float(radius_px)
    for k, (pu, pv) in enumerate(pred):
        u0, u1 = max(int(np.floor(pu - r)), h), min(int(np.ceil(pu + r)) + 1, cols - h)
        v0, v1 = max(int(np.floor(pv - r)), h), min(int(np.ceil(pv + r)) + 1, rows - h)
        if u1 <= u0 or v1 <= v0:
            continue
        vv, uu = np.mgrid[v0:v1, u0:u1]
        win = np.where((uu - pu) ** 2 + (vv - pv) ** 2 <= r * r, img[v0:v1, u0:u1], -np.inf)
        j = int(np.argmax(win))
        mv, mu = v0 + j // win.shape[1], u0 + j % win.shape[1]
        box = img[mv - h:mv + h + 1, mu - h:mu + h + 1]
        border = np.concatenate([box[0], box[-1], box[1:-1, 0], box[1:-1, -1]])
        b = float(np.median(border))
        if not box[h, h] - b > min_snr * sigma:
            continue
        w = np.clip(box - b, 0.0, None)
        by, bx = np.mgrid[-h:h + 1, -h:h + 1]
        out[k] = (mu + float((w * bx).sum() / w.sum()), mv + float((w * by).sum() / w.sum()))
    return out


def rectify_sensor(image: np.ndarray, maps: tuple[np.ndarray, np.ndarray], saturated_at: int) -> np.ndarray:
    """One sensor's raw image resampled onto the target grid (bilinear, :func:`remap`), its
    saturation kept: every output pixel whose bilinear footprint touches a source pixel at or
    above ``saturated_at`` reads ``saturated_at`` (so may a pixel just beside such a footprint).
    A bilinear mix of a clipped and an unclipped pixel is neither a measurement nor flagged as
    clipped; an HDR merge would take it at face value. Output dtype = input dtype."""
    img = np.asarray(image)
    out = remap(img, maps)
    sat = img >= saturated_at
    if sat.any():
        # A bilinear footprint is the 2x2 source pixels around the map point, all within one
        # pixel of the nearest one: the clipped mask grown by one pixel, sampled nearest, marks
        # every output pixel whose footprint touches it (and a few beside it, which then merge
        # from the other sensor). Half the cost of a bilinear float mask.
        grown = cv2.dilate(sat.view(np.uint8), np.ones((3, 3), np.uint8))
        out[remap(grown, maps, cv2.INTER_NEAREST) > 0] = saturated_at
    return out
