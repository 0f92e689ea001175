"""Camera-to-target registration (controller.imaging.registration).

Synthetic: a camera 60 m north of and 28 m below a north-facing 8.6 m × 7.2 m target (Jülich-like
geometry), f = 4700 px, 1024×768, radial + tangential distortion, and a pose error (5 mrad,
0.3 m) against its nominal look-at pose, sees the target's corners and a grid of interior
fiducials with 0.05 px Gaussian pixel noise. Real: the Jülich tower seen in 106293-raw.png,
registered on eight hand-picked fiducials (tests/data/real/paint/106293-raw-fiducials.json),
rectified and compared with PAINT's own rectified crop 106293-cropped.png.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from controller.errors import InputError
from controller.geometry.frames import wgs84_to_enu
from controller.geometry.target_frame import TargetFrame
from controller.imaging.beam import analyze
from controller.imaging.registration import CameraModel, PlaneGrid, rectify, register

REAL = Path(__file__).resolve().parents[1] / "data" / "real"
PAINT = REAL / "paint"

CENTER = np.array([0.0, 0.0, 130.0])
NORMAL = np.array([0.0, 1.0, 0.0])
W_M, H_M = 8.6, 7.2
SIZE = (1024, 768)  # (width, height) px
K_TRUE = np.array([[4700.0, 0, 530.0], [0, 4700.0, 370.0], [0, 0, 1]])
DIST_TRUE = np.array([-0.3, 0.5, 2e-4, -1e-4, 0.0])


def _look_at(cam: np.ndarray, at: np.ndarray) -> np.ndarray:
    z = (at - cam) / np.linalg.norm(at - cam)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    return np.vstack([x, np.cross(z, x), z])


def _true_camera() -> CameraModel:
    nominal_c = np.array([2.0, 60.0, 102.0])
    r = cv2.Rodrigues(np.array([0.005, -0.003, 0.004]))[0] @ _look_at(nominal_c, CENTER)  # pose error
    c = nominal_c + np.array([0.3, -0.2, 0.1])
    return CameraModel(K_TRUE, DIST_TRUE, cv2.Rodrigues(r)[0].ravel(), -r @ c, SIZE)


def _target_points(nx: int, ny: int) -> np.ndarray:
    """An nx × ny grid of fiducials spanning the target, corners included (m ENU)."""
    s, t = np.meshgrid(np.linspace(-0.5, 0.5, nx), np.linspace(-0.5, 0.5, ny))
    u, v = np.array([-1.0, 0, 0]), np.array([0, 0, -1.0])  # image right = west, down
    return CENTER + (s.ravel() * W_M)[:, None] * u + (t.ravel() * H_M)[:, None] * v


def _observe(cam: CameraModel, pts: np.ndarray, noise_px: float = 0.05, seed: int = 0) -> np.ndarray:
    return cam.project(pts) + np.random.default_rng(seed).normal(0.0, noise_px, (len(pts), 2))


def _rot_err_mrad(a: CameraModel, b: CameraModel) -> float:
    return 1e3 * float(np.linalg.norm(cv2.Rodrigues(a.rotation @ b.rotation.T)[0]))


@pytest.mark.parametrize("seed", range(3))
def test_pose_recovered_with_known_intrinsics(seed):
    # Measured over seeds 0-4: rotation 0.06-0.52 mrad, centre 4-35 mm. With a 12° field of
    # view a small rotation and a sideways shift look alike, hence the tolerances.
    cam = _true_camera()
    pts = _target_points(5, 5)
    known = CameraModel(K_TRUE, DIST_TRUE, np.zeros(3), np.zeros(3), SIZE)
    reg = register(pts, _observe(cam, pts, seed=seed), SIZE, fix_intrinsics=known)
    assert reg.fitted == "pose"
    assert reg.rms_px < 0.1
    assert _rot_err_mrad(reg.model, cam) < 1.0
    assert np.linalg.norm(reg.model.center_enu - cam.center_enu) < 0.1  # m, at 65 m range
    check = _target_points(37, 31)
    assert np.abs(reg.model.project(check) - cam.project(check)).max() < 0.05


@pytest.mark.parametrize("seed", range(3))
def test_plane_to_image_map_recovered_with_unknown_intrinsics(seed):
    # One view of a plane through a 12° lens fixes the plane-to-image map (homography +
    # distortion), not f, principal point and pose separately (measured over seeds 0-4: f off
    # by up to 8 %, rotation by up to 42 mrad). The map is what the beam chain needs: checked on
    # a dense grid between the fiducials.
    cam = _true_camera()
    pts = _target_points(11, 9)
    reg = register(pts, _observe(cam, pts, seed=seed), SIZE)
    assert reg.fitted == "intrinsics+pose"
    assert reg.rms_px < 0.1
    assert reg.residuals_px.shape == (99, 2)
    check = _target_points(37, 31)
    assert np.abs(reg.model.project(check) - cam.project(check)).max() < 0.1


def test_a_3d_rig_separates_focal_length_and_range():
    # Every other fiducial 3 m in front of the target: depth breaks the planar degeneracy.
    # Measured over seeds 0-2: f within 0.12 %, centre within 7 cm, RMS 0.064-0.067 px.
    cam = _true_camera()
    pts = _target_points(11, 9)
    pts = pts + 3.0 * NORMAL * (np.arange(len(pts)) % 2)[:, None]
    reg = register(pts, _observe(cam, pts), SIZE)
    assert reg.rms_px < 0.1
    assert abs(reg.model.K[0, 0] / K_TRUE[0, 0] - 1) < 0.005
    assert np.linalg.norm(reg.model.center_enu - cam.center_enu) < 0.2


def test_pixel_to_target_inverts_project():
    cam = _true_camera()
    pts = _target_points(21, 17)
    back = cam.pixel_to_target(cam.project(pts), CENTER, NORMAL)
    assert np.abs(back - pts).max() < 1e-3  # m
    px = np.array([[3.0, 5.0], [512.0, 384.0], [1020.0, 760.0]])
    on_plane = cam.pixel_to_target(px, CENTER, NORMAL)
    assert np.abs((on_plane - CENTER) @ NORMAL).max() < 1e-9
    assert np.abs(cam.project(on_plane) - px).max() < 1e-6


def test_rectify_puts_a_rendered_spot_at_its_target_frame_pixel():
    cam = _true_camera()
    pts = _target_points(11, 9)
    model = register(pts, _observe(cam, pts), SIZE).model
    spot = CENTER + np.array([-1.3, 0.0, 0.8])  # 1.3 m west, 0.8 m up
    # Render: each camera pixel sees the target point its ray hits; a Gaussian irradiance there.
    vv, uu = np.mgrid[0:SIZE[1], 0:SIZE[0]]
    seen = cam.pixel_to_target(np.column_stack([uu.ravel(), vv.ravel()]), CENTER, NORMAL)
    raw = 200.0 * np.exp(-0.5 * np.sum((seen - spot) ** 2, axis=1) / 0.4**2).reshape(vv.shape) + 10.0
    frame = TargetFrame.from_config(SimpleNamespace(normal=NORMAL, center_enu_m=CENTER, width_m=W_M,
                                                    height_m=H_M), (192, 256))
    rect = rectify(raw.astype(np.float32), model, frame)
    assert rect.shape == (192, 256)
    expect = PlaneGrid.from_frame(frame).enu_to_pixel(spot)[0]
    got = np.array(analyze(rect, threshold=0.05).centroid_px)
    assert np.hypot(*(got - expect)) < 0.1, (got, expect)
    # The identity model (no registration) would not do: the raw spot sits elsewhere.
    assert np.hypot(*(np.array(analyze(raw).centroid_px) - expect)) > 50


@pytest.mark.parametrize("obj, img, match", [
    (np.zeros((3, 3)), np.zeros((3, 2)), "at least 4"),
    (np.c_[np.arange(5.0), np.zeros(5), np.zeros(5)], np.random.default_rng(1).random((5, 2)), "collinear"),
    (np.random.default_rng(2).random((6, 3)), np.random.default_rng(3).random((5, 2)), "6 target points"),
    (np.full((5, 3), np.nan), np.zeros((5, 2)), "NaN"),
    (np.zeros((5, 2)), np.zeros((5, 2)), r"\(N, 3\)"),
])
def test_bad_inputs_refused(obj, img, match):
    with pytest.raises(InputError, match=match):
        register(obj, img, SIZE)


def test_too_few_points_for_the_intrinsics_and_bad_fit_refused():
    cam = _true_camera()
    pts = _target_points(3, 2)
    with pytest.raises(InputError, match="unknowns"):
        register(pts, cam.project(pts), SIZE)
    pts = _target_points(5, 5)
    obs = _observe(cam, pts)
    obs[7] += 25.0  # one misidentified fiducial
    known = CameraModel(K_TRUE, DIST_TRUE, np.zeros(3), np.zeros(3), SIZE)
    with pytest.raises(InputError, match="RMS .* exceeds .*point 7"):
        register(pts, obs, SIZE, fix_intrinsics=known)


def test_non_planar_pose_needs_six_points_and_rectify_needs_a_grey_image():
    cam = _true_camera()
    off_plane = np.array([0.0, 1.0, -1.0, 2.0, 0.5])[:, None] * NORMAL  # 5 points, not coplanar
    pts = _target_points(3, 2)[:5] + off_plane
    known = CameraModel(K_TRUE, DIST_TRUE, np.zeros(3), np.zeros(3), SIZE)
    with pytest.raises(InputError, match="at least 6"):
        register(pts, cam.project(pts), SIZE, fix_intrinsics=known)
    frame = PlaneGrid.from_corners(CENTER, CENTER + [-1.0, 0, 0], CENTER + [0, 0, -1.0], (8, 8))
    with pytest.raises(InputError, match="2-D grey"):
        rectify(np.zeros((768, 1024, 3), np.uint8), cam, frame)


def test_pixel_to_target_is_nan_for_a_plane_behind_the_camera():
    cam = _true_camera()
    behind = cam.center_enu + np.array([0.0, 10.0, 0.0])  # 10 m north of a camera looking south
    assert np.isnan(cam.pixel_to_target(np.array([[512.0, 384.0]]), behind, NORMAL)).all()


# --- real data: the Jülich tower in 106293-raw.png ---------------------------------------

def _real_registration():
    towers = json.loads((REAL / "aa39" / "tower-measurements.json").read_text())
    origin = towers["power_plant_properties"]["coordinates"]
    picked = json.loads((PAINT / "106293-raw-fiducials.json").read_text())["points_px"]

    def enu(key: str) -> np.ndarray:
        target, corner = key.split(".")
        return wgs84_to_enu(*towers[target]["coordinates"][corner], *origin)

    obj = np.array([enu(k) for k in picked])
    img = np.array(list(picked.values()))
    raw = cv2.cvtColor(cv2.imread(str(PAINT / "106293-raw.png")), cv2.COLOR_BGR2GRAY)
    reg = register(obj, img, (raw.shape[1], raw.shape[0]), radial_terms=1, tangential=False,
                   fix_principal_point=True, max_rms_px=3.0)
    return reg, raw, enu


def test_real_registration_reproduces_the_paint_crop():
    reg, raw, enu = _real_registration()
    assert reg.rms_px < 2.0  # hand-picked to ~1-2 raw px
    up = "solar_tower_juelich_upper."
    grid = PlaneGrid.from_corners(enu(up + "upper_left"), enu(up + "upper_right"), enu(up + "lower_left"),
                                  (256, 256))
    # ~4.6 x 7.4 raw px per crop px: low-pass before bilinear sampling.
    rect = rectify(cv2.GaussianBlur(raw, (0, 0), 2.5).astype(np.float32), reg.model, grid)
    crop = cv2.imread(str(PAINT / "106293-cropped.png"), cv2.IMREAD_GRAYSCALE).astype(np.float32)
    a, b = rect - rect.mean(), crop - crop.mean()
    ncc = float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))
    shift, _ = cv2.phaseCorrelate(crop.astype(np.float64), rect.astype(np.float64))
    assert ncc > 0.9, ncc
    assert np.hypot(*shift) < 1.5, shift
    c_rect = np.array(analyze(rect).centroid_px)
    c_crop = np.array(analyze(crop).centroid_px)
    assert np.hypot(*(c_rect - c_crop)) < 2.0, (c_rect, c_crop)
