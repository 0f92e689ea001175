"""Camera-to-target registration: a calibrated camera model and the remap into the target frame.

Camera model (pinhole + Brown-Conrady distortion, the OpenCV model). A point X (m, ENU) goes to
camera coordinates with the pose ``rvec``/``tvec`` (target/ENU → camera, Rodrigues vector, m):

    X_c = R(rvec) X + tvec,            x' = X_c / Z_c,  y' = Y_c / Z_c   (camera looks along +Z_c)
    r² = x'² + y'²
    x'' = x'(1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x'y' + p2 (r² + 2x'²)
    y'' = y'(1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2y'²) + 2 p2 x'y'
    u = fx x'' + cx,                   v = fy y'' + cy                   (px)

with K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (px) and ``dist`` = (k1, k2, p1, p2, k3)
(dimensionless). Pixel coordinates: u = column, v = row, (0, 0) the centre of the top-left pixel.
The inverse (:meth:`CameraModel.pixel_to_target`) undoes the distortion iteratively and intersects
the viewing ray C + s·d (C = -Rᵀ tvec the camera centre, d = Rᵀ (x', y', 1)) with the target plane.

:func:`register` fits the model to surveyed target points seen in one image: the pose alone
(solvePnP, IPPE for a planar target, then Levenberg-Marquardt) when the intrinsics are known, or
intrinsics + pose (``cv2.calibrateCamera`` on the single view, homography-initialised for a
planar target) when not. One view of a plane fixes the plane→image map, not f and the distance
separately: with unknown intrinsics the pose is only as good as the perspective in the view.
:func:`rectify` resamples a camera image onto a target-plane pixel grid (``cv2.remap``), so the
beam chain, written for rectified views, runs unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from controller.errors import InputError

DEFAULT_MAX_RMS_PX = 1.0
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


def _undistort(uv: np.ndarray, k: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Normalised (x', y') of distorted pixels, iterated to ``_UNDISTORT_CRITERIA`` (OpenCV 4
    names this undistortPointsIter; OpenCV 5 gives undistortPoints the criteria argument)."""
    if hasattr(cv2, "undistortPointsIter"):
        return cv2.undistortPointsIter(uv, k, dist, None, None, _UNDISTORT_CRITERIA)
    return cv2.undistortPoints(uv, k, dist, criteria=_UNDISTORT_CRITERIA)


@dataclass(frozen=True, eq=False)  # numpy fields
class CameraModel:
    """Intrinsics ``K`` (3×3, px), distortion ``dist`` (k1, k2, p1, p2, k3), pose ``rvec``/``tvec``
    (ENU → camera, rad / m) and ``image_size`` (width, height) px. See the module docstring."""

    K: np.ndarray
    dist: np.ndarray
    rvec: np.ndarray
    tvec: np.ndarray
    image_size: tuple[int, int]

    @property
    def rotation(self) -> np.ndarray:
        """R (3×3): camera coordinates = R · ENU + tvec."""
        return cv2.Rodrigues(np.asarray(self.rvec, float).reshape(3, 1))[0]

    @property
    def center_enu(self) -> np.ndarray:
        """Camera centre C = -Rᵀ tvec, m ENU."""
        return -self.rotation.T @ np.asarray(self.tvec, float).reshape(3)

    def project(self, points_enu: np.ndarray) -> np.ndarray:
        """Pixel (u, v) of each ENU point: (N, 3) m → (N, 2) px (module docstring equations)."""
        p = np.asarray(points_enu, dtype=np.float64).reshape(-1, 3)
        u, v = self._camera_to_pixel(p @ self.rotation.T + np.asarray(self.tvec, float).reshape(3))
        return np.column_stack([u, v])

    def _camera_to_pixel(self, xc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(u, v) of camera-frame points (..., 3): the module docstring's distortion and K, in
        numpy (cv2.projectPoints also builds Jacobians, 10x slower on the million points of a
        remap table; the tests check both agree)."""
        x, y = xc[..., 0] / xc[..., 2], xc[..., 1] / xc[..., 2]
        k1, k2, p1, p2, k3 = (list(np.asarray(self.dist, float).reshape(-1)) + [0.0] * 5)[:5]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        k = np.asarray(self.K, float)
        return k[0, 0] * xd + k[0, 1] * yd + k[0, 2], k[1, 1] * yd + k[1, 2]

    def pixel_to_target(self, px: np.ndarray, plane_point: np.ndarray, plane_normal: np.ndarray
                        ) -> np.ndarray:
        """ENU point (N, 3) m where the ray of each pixel (N, 2) meets the plane through
        ``plane_point`` with normal ``plane_normal``. Undistortion iterates to 1e-12 (normalised
        units); NaN rows for rays parallel to the plane or hitting it behind the camera."""
        uv = np.asarray(px, dtype=np.float64).reshape(-1, 1, 2)
        xn = _undistort(uv, np.asarray(self.K, float), np.asarray(self.dist, float)).reshape(-1, 2)
        r = self.rotation
        d = np.column_stack([xn, np.ones(len(xn))]) @ r  # rows: Rᵀ (x', y', 1)
        c = self.center_enu
        n = np.asarray(plane_normal, float).reshape(3)
        denom = d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            s = ((np.asarray(plane_point, float).reshape(3) - c) @ n) / denom
        s = np.where((np.abs(denom) > 1e-12) & (s > 0), s, np.nan)
        return c + s[:, None] * d


@dataclass(frozen=True, eq=False)
class Registration:
    """Result of :func:`register`: the model, reprojection RMS (px), per-point residuals
    (N, 2) px = projected − observed, and what was fitted (``"pose"`` or ``"intrinsics+pose"``)."""

    model: CameraModel
    rms_px: float
    residuals_px: np.ndarray
    fitted: str


def _check_points(obj, img) -> tuple[np.ndarray, np.ndarray]:
    try:
        o = np.asarray(obj, dtype=np.float64)
        i = np.asarray(img, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"registration points must be numeric arrays: {exc}") from None
    if o.ndim != 2 or o.shape[1] != 3 or i.ndim != 2 or i.shape[1] != 2:
        raise InputError(f"registration needs (N, 3) target points and (N, 2) pixels, "
                         f"got {o.shape} and {i.shape}")
    if len(o) != len(i):
        raise InputError(f"registration: {len(o)} target points but {len(i)} pixels")
    if len(o) < 4:
        raise InputError(f"registration needs at least 4 point pairs, got {len(o)}")
    if not (np.isfinite(o).all() and np.isfinite(i).all()):
        raise InputError("registration points contain NaN or infinite values")
    for name, p in (("target points", o), ("image points", i)):
        s = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
        if not s[0] > 0 or s[1] < 1e-6 * s[0]:
            raise InputError(f"registration {name} are degenerate (coincident or collinear)")
    return o, i


def _plane_axes(o: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """(origin, E, planar): E (3×3, det +1) has rows e1, e2 in the points' best plane and e3 its
    normal; ``planar`` when the out-of-plane spread is below 1 % of the in-plane one (surveyed
    corners of a flat target scatter by ~0.1 %: 2 cm on the 17 m Jülich tower)."""
    origin = o.mean(axis=0)
    _, s, vt = np.linalg.svd(o - origin)
    e = vt.copy()
    if np.linalg.det(e) < 0:
        e[2] *= -1
    return origin, e, bool(s[2] < 1e-2 * s[0])


def _calib_flags(radial_terms: int, tangential: bool, fix_principal_point: bool) -> int:
    flags = cv2.CALIB_FIX_ASPECT_RATIO
    for k, flag in enumerate((cv2.CALIB_FIX_K1, cv2.CALIB_FIX_K2, cv2.CALIB_FIX_K3), start=1):
        if k > radial_terms:
            flags |= flag
    if not tangential:
        flags |= cv2.CALIB_ZERO_TANGENT_DIST
    if fix_principal_point:
        flags |= cv2.CALIB_FIX_PRINCIPAL_POINT
    return flags


def _fit_intrinsics(local: np.ndarray, i: np.ndarray, size: tuple[int, int], flags: int, planar: bool):
    """calibrateCamera on one view in the plane frame; (K, dist, rvec, tvec) of local → camera."""
    w, h = size
    k0 = np.array([[1.0, 0, (w - 1) / 2], [0, 1.0, (h - 1) / 2], [0, 0, 1]])
    img = [i.astype(np.float32).reshape(-1, 1, 2)]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    if planar:
        # Homography initialisation needs z = 0 exactly; refine on the real 3-D points next.
        flat = local.copy()
        flat[:, 2] = 0.0
        _, k, dist, _, _ = cv2.calibrateCamera([flat.astype(np.float32)], img, (w, h), k0, np.zeros(5),
                                               flags=flags, criteria=crit)
    else:
        f0 = float(max(w, h))
        k = np.array([[f0, 0, (w - 1) / 2], [0, f0, (h - 1) / 2], [0, 0, 1]])
        dist = np.zeros(5)
    _, k, dist, rv, tv = cv2.calibrateCamera([local.astype(np.float32)], img, (w, h), k, dist,
                                             flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS, criteria=crit)
    return k, np.asarray(dist, float).reshape(-1)[:5], rv[0].reshape(3), tv[0].reshape(3)


def _fit_pose(local: np.ndarray, i: np.ndarray, k: np.ndarray, dist: np.ndarray, planar: bool):
    method = cv2.SOLVEPNP_IPPE if planar else cv2.SOLVEPNP_ITERATIVE
    if not planar and len(local) < 6:
        raise InputError(f"registration of a non-planar point set needs at least 6 points, got {len(local)}")
    pts = local.copy()
    if planar:
        pts[:, 2] = 0.0  # IPPE wants the plane z = 0; the LM refinement below uses the real points
    ok, rv, tv = cv2.solvePnP(pts, i, k, dist, flags=method)
    if not ok:
        raise InputError("registration: solvePnP found no pose for these points")
    rv, tv = cv2.solvePnPRefineLM(local, i, k, dist, rv, tv,
                                  (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12))
    return rv.reshape(3), tv.reshape(3)


def register(object_points_enu, image_points_px, image_size: tuple[int, int], *,
             fix_intrinsics: CameraModel | None = None, radial_terms: int = 2, tangential: bool = True,
             fix_principal_point: bool = False, max_rms_px: float = DEFAULT_MAX_RMS_PX) -> Registration:
    """Fit a :class:`CameraModel` to N ≥ 4 surveyed target points (N, 3) m ENU and their pixels
    (N, 2) in an image of ``image_size`` (width, height) px.

    ``fix_intrinsics``: a model whose K and dist are kept (e.g. from a lab calibration); only
    the pose is fitted. Otherwise K (fx = fy), the first ``radial_terms`` (0–3) of k1, k2, k3,
    p1/p2 when ``tangential``, and the principal point unless ``fix_principal_point`` (then the
    image centre) are fitted with the pose; this needs 2N ≥ 6 + number of intrinsics.
    Refuses (InputError): fewer than 4 points, mismatched/non-finite arrays, coincident or
    collinear points, too few points for the unknowns, reprojection RMS above ``max_rms_px``.
    """
    o, i = _check_points(object_points_enu, image_points_px)
    w, h = (int(image_size[0]), int(image_size[1]))
    if w <= 0 or h <= 0:
        raise InputError(f"registration image_size must be positive (width, height), got {image_size}")
    origin, e, planar = _plane_axes(o)
    local = (o - origin) @ e.T
    if fix_intrinsics is None:
        if not 0 <= radial_terms <= 3:
            raise InputError(f"radial_terms must be 0..3, got {radial_terms}")
        unknowns = 6 + 1 + radial_terms + 2 * bool(tangential) + 2 * (not fix_principal_point)
        if 2 * len(o) < unknowns:
            raise InputError(f"registration: {len(o)} points give {2 * len(o)} equations for {unknowns} "
                             f"unknowns; add points or fit fewer intrinsics")
        flags = _calib_flags(radial_terms, tangential, fix_principal_point)
        k, dist, rv_l, tv_l = _fit_intrinsics(local, i, (w, h), flags, planar)
        fitted = "intrinsics+pose"
    else:
        k = np.asarray(fix_intrinsics.K, float)
        dist = np.asarray(fix_intrinsics.dist, float).reshape(-1)[:5]
        rv_l, tv_l = _fit_pose(local, i, k, dist, planar)
        fitted = "pose"
    # X_c = R_l (E (X - o)) + t_l  =>  R = R_l E,  t = t_l - R_l E o
    r_l = cv2.Rodrigues(rv_l.reshape(3, 1))[0]
    r = r_l @ e
    model = CameraModel(K=k, dist=dist, rvec=cv2.Rodrigues(r)[0].reshape(3), tvec=tv_l - r @ origin,
                        image_size=(w, h))
    resid = model.project(o) - i
    rms = float(np.sqrt(np.mean(np.sum(resid**2, axis=1))))
    if not rms <= max_rms_px:
        worst = int(np.argmax(np.hypot(*resid.T)))
        raise InputError(f"registration reprojection RMS {rms:.2f} px exceeds {max_rms_px} px "
                         f"(worst: point {worst}, {np.hypot(*resid[worst]):.2f} px)")
    return Registration(model=model, rms_px=rms, residuals_px=resid, fitted=fitted)


@dataclass(frozen=True, eq=False)
class PlaneGrid:
    """An affine pixel grid on the target plane: pixel (x, y) (x = column, y = row) ↦
    ``origin + x·step_x + y·step_y`` (m ENU); ``shape`` (rows, cols)."""

    origin: np.ndarray
    step_x: np.ndarray
    step_y: np.ndarray
    shape: tuple[int, int]

    @classmethod
    def from_frame(cls, frame) -> PlaneGrid:
        """The grid of a :class:`controller.geometry.target_frame.TargetFrame` (or anything with
        an affine ``pixel_to_enu(x, y)`` and ``shape``)."""
        p0 = np.asarray(frame.pixel_to_enu(0.0, 0.0), float)
        return cls(p0, np.asarray(frame.pixel_to_enu(1.0, 0.0), float) - p0,
                   np.asarray(frame.pixel_to_enu(0.0, 1.0), float) - p0, tuple(frame.shape))

    @classmethod
    def from_corners(cls, upper_left, upper_right, lower_left, shape: tuple[int, int]) -> PlaneGrid:
        """The PAINT crop convention: corner ``upper_left`` at pixel (0, 0) and x = s·cols,
        y = t·rows for the fractions s, t along the top and left edges."""
        ul = np.asarray(upper_left, float)
        rows, cols = int(shape[0]), int(shape[1])
        step_x = (np.asarray(upper_right, float) - ul) / cols
        return cls(ul, step_x, (np.asarray(lower_left, float) - ul) / rows, (rows, cols))

    def pixel_to_enu(self, x_px, y_px) -> np.ndarray:
        """ENU (..., 3) of pixel coordinates (scalars or arrays of one shape)."""
        x = np.asarray(x_px, float)[..., None]
        y = np.asarray(y_px, float)[..., None]
        return self.origin + x * self.step_x + y * self.step_y

    def enu_to_pixel(self, points_enu) -> np.ndarray:
        """(x, y) px (N, 2) of ENU points, least squares onto the grid's plane."""
        a = np.column_stack([self.step_x, self.step_y])
        d = np.asarray(points_enu, float).reshape(-1, 3) - self.origin
        return np.linalg.lstsq(a, d.T, rcond=None)[0].T


def rectification_maps(model: CameraModel, frame) -> tuple[np.ndarray, np.ndarray]:
    """(map_x, map_y), float32 (rows, cols): the camera pixel each target-frame pixel sees.
    Compute once per camera model and frame; :func:`remap` is then the per-image cost."""
    grid = frame if isinstance(frame, PlaneGrid) else PlaneGrid.from_frame(frame)
    rows, cols = grid.shape
    r, t = model.rotation, np.asarray(model.tvec, float).reshape(3)
    # The grid is affine in (x, y), so are its camera-frame points: X_c = a + x·b + y·c, built
    # by broadcasting instead of a million ENU points.
    a, b, c = r @ grid.origin + t, r @ grid.step_x, r @ grid.step_y
    xc = a + np.arange(cols, dtype=float)[None, :, None] * b + np.arange(rows, dtype=float)[:, None, None] * c
    u, v = model._camera_to_pixel(xc)
    return u.astype(np.float32), v.astype(np.float32)


def remap(image: np.ndarray, maps: tuple[np.ndarray, np.ndarray], interpolation: int = cv2.INTER_LINEAR
          ) -> np.ndarray:
    """Resample ``image`` through ``maps`` (bilinear by default). Target pixels whose camera
    pixel lies outside the image get 0. uint8/uint16/float32 keep their type, other types go
    through float32."""
    img = np.asarray(image)
    if img.ndim != 2 or img.size == 0:
        raise InputError(f"rectify expects a non-empty 2-D grey image, got shape {img.shape}")
    if img.dtype not in (np.uint8, np.uint16, np.float32):
        img = img.astype(np.float32)
    return cv2.remap(img, maps[0], maps[1], interpolation, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def rectify(image: np.ndarray, model: CameraModel, frame, interpolation: int = cv2.INTER_LINEAR
            ) -> np.ndarray:
    """The camera ``image`` resampled onto ``frame`` (a TargetFrame or :class:`PlaneGrid`):
    output pixel (x, y) = image at ``model.project(frame.pixel_to_enu(x, y))``. Shape
    ``frame.shape``. When the frame's pixels are much larger than the camera's, low-pass the
    image first (bilinear sampling aliases)."""
    return remap(image, rectification_maps(model, frame), interpolation)
