"""``heliocal flux`` and ``heliocal glare``: JSON contracts, outputs and clean refusals (exit 2)."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from controller.cli import main

DNI, RHO, T_SUN, T_EXP = 900.0, 0.85, 0.01, 1e-3
CONTRACT = {"peak_w_m2", "mean_w_m2", "sun_radius_px", "sun_center_px", "hotspots", "saturated_px"}


def _run(capsys, argv):
    code = main(argv)
    out = capsys.readouterr().out.strip().splitlines()
    return code, (json.loads(out[-1]) if out else None)


def _png(path, img):
    assert cv2.imwrite(str(path), img)
    return str(path)


@pytest.fixture(scope="module")
def scene(tmp_path_factory, camera, beam):
    """Sun, receiver (beam at 100 m, 30° view) and ambient PNGs plus the truth (rendered once)."""
    tmp_path = tmp_path_factory.mktemp("scene")
    rng = np.random.default_rng(8)
    field, power = beam()
    theta = np.radians(30.0)
    rate = camera.target_rate(field, RHO, 100.0, theta)
    files = {
        "sun": _png(tmp_path / "sun.png", camera.expose(camera.sun_rate(DNI, T_SUN), T_EXP, rng)),
        "receiver": _png(tmp_path / "receiver.png", camera.expose(rate, T_EXP, rng)),
        "ambient": _png(tmp_path / "ambient.png", camera.expose(0 * rate, T_EXP, rng)),
    }
    return files, camera.truth(field, 100.0, theta), power


def _flux_argv(files, tmp_path, *extra):
    return [
        "flux",
        files["receiver"],
        "--sun",
        files["sun"],
        "--ambient",
        files["ambient"],
        "--dni",
        str(DNI),
        "--reflectivity",
        str(RHO),
        "--sun-transmittance",
        str(T_SUN),
        "--out",
        str(tmp_path / "flux.npy"),
        "--json",
        *extra,
    ]


def test_flux_end_to_end(capsys, tmp_path, scene):
    files, truth, power = scene
    code, res = _run(
        capsys,
        _flux_argv(
            files,
            tmp_path,
            "--distance",
            "100",
            "--view-angle-deg",
            "30",
            "--png",
            str(tmp_path / "flux.png"),
        ),
    )
    assert code == 0
    assert set(res) == CONTRACT | {"total_power_w"}
    flux = np.load(tmp_path / "flux.npy")
    assert flux.dtype == np.float32 and flux.shape == truth.shape
    assert res["peak_w_m2"] == pytest.approx(float(flux.max()), rel=1e-6)
    assert res["mean_w_m2"] == pytest.approx(float(flux.mean()), rel=1e-5)
    assert res["total_power_w"] == pytest.approx(power, rel=0.02)
    assert res["sun_radius_px"] == pytest.approx(40.0, abs=0.5)
    assert res["sun_center_px"] == pytest.approx([129.8, 99.3], abs=0.2)
    beam = truth >= 0.1 * truth.max()
    assert np.sqrt(np.mean((flux[beam] - truth[beam]) ** 2)) / truth[beam].mean() < 0.03
    top = res["hotspots"][0]
    assert set(top) == {"x", "y", "w_m2"}
    peak_y, peak_x = np.unravel_index(np.argmax(truth), truth.shape)
    assert abs(top["x"] - peak_x) <= 3 and abs(top["y"] - peak_y) <= 3
    png = cv2.imread(str(tmp_path / "flux.png"))
    assert png is not None and png.ndim == 3


def test_total_power_only_with_distance(capsys, tmp_path, scene):
    files, _, _ = scene
    code, res = _run(capsys, _flux_argv(files, tmp_path))
    assert code == 0 and set(res) == CONTRACT


def test_flux_from_double_ccd_pairs(capsys, tmp_path, camera, rng, beam):
    # HIGH (4 ms) saturates the beam core, LOW (0.5 ms) does not; the sun was taken at 1 ms.
    field, power = beam(peak_w_m2=400e3)
    rate = camera.target_rate(field, RHO, 100.0, 0.0)
    sun = _png(tmp_path / "sun.png", camera.expose(camera.sun_rate(DNI, T_SUN), T_EXP, rng))
    pair = [_png(tmp_path / f"rx_{t}.png", camera.expose(rate, t, rng)) for t in (5e-4, 4e-3)]
    dark = [_png(tmp_path / f"amb_{t}.png", camera.expose(0 * rate, t, rng)) for t in (5e-4, 4e-3)]
    assert cv2.imread(pair[1], cv2.IMREAD_UNCHANGED).max() == 255
    code, res = _run(
        capsys,
        [
            "flux",
            "--receiver-pair",
            *pair,
            "--ambient-pair",
            *dark,
            "--exposures",
            "0.0005",
            "0.004",
            "--sun-exposure",
            "0.001",
            "--sun",
            sun,
            "--dni",
            str(DNI),
            "--reflectivity",
            str(RHO),
            "--sun-transmittance",
            str(T_SUN),
            "--distance",
            "100",
            "--out",
            str(tmp_path / "f.npy"),
            "--json",
        ],
    )
    assert code == 0
    assert res["total_power_w"] == pytest.approx(power, rel=0.02)
    assert res["peak_w_m2"] == pytest.approx(camera.truth(field, 100.0, 0.0).max(), rel=0.05)


def _bad(tmp_path, camera, rng, files, case):
    argv = _flux_argv(files, tmp_path)
    if case == "saturated sun":
        argv[argv.index("--sun") + 1] = _png(
            tmp_path / "hot.png", camera.expose(camera.sun_rate(DNI, 3 * T_SUN), T_EXP, rng)
        )
    elif case == "no disc":
        argv[argv.index("--sun") + 1] = _png(
            tmp_path / "cloud.png", camera.expose(np.zeros(camera.shape), T_EXP, rng)
        )
    elif case == "ambient size":
        argv[argv.index("--ambient") + 1] = _png(tmp_path / "small.png", np.full((100, 100), 8, np.uint8))
    elif case == "sun size":
        argv[argv.index("--sun") + 1] = _png(tmp_path / "big.png", np.full((300, 300), 8, np.uint8))
    elif case == "missing file":
        argv[1] = str(tmp_path / "nope.png")
    elif case == "reflectivity":
        argv[argv.index("--reflectivity") + 1] = "1.5"
    elif case == "angle without distance":
        argv += ["--view-angle-deg", "30"]
    elif case == "corrupt image":
        (tmp_path / "junk.png").write_bytes(b"not a png")
        argv[1] = str(tmp_path / "junk.png")
    return argv


@pytest.mark.parametrize(
    "case, words",
    [
        ("saturated sun", "saturated"),
        ("no disc", "no sun disc"),
        ("ambient size", "sizes differ"),
        ("sun size", "sizes differ"),
        ("missing file", "not found"),
        ("reflectivity", "--reflectivity"),
        ("angle without distance", "--distance"),
        ("corrupt image", "junk.png"),
    ],
)
def test_flux_bad_input_exits_2_and_writes_nothing(capsys, tmp_path, camera, rng, scene, case, words):
    files, _, _ = scene
    code, res = _run(capsys, _bad(tmp_path, camera, rng, files, case))
    assert code == 2
    assert res["ok"] is False and words in res["error"]
    assert "\n" not in res["error"]
    assert not (tmp_path / "flux.npy").exists()


def test_glare_direct(capsys, tmp_path):
    code, res = _run(
        capsys,
        [
            "glare",
            "--corneal-irradiance-w-m2",
            "1000",
            "--subtended-angle-mrad",
            "9.3",
            "--json",
            "--png",
            str(tmp_path / "h.png"),
        ],
    )
    assert code == 0
    assert res == {
        "retinal_irradiance_w_cm2": pytest.approx(8.00141, rel=1e-5),
        "subtended_angle_mrad": pytest.approx(9.3),
        "zone": "yellow",
    }
    assert cv2.imread(str(tmp_path / "h.png")) is not None


def test_glare_from_images(capsys, tmp_path, camera, rng, disc_renderer):
    # A 100 W/m² glint of radius 10 px through ND 4e-3: ω = 9.3·10/40 = 2.325 mrad,
    # E_r = 100·4e-6·0.5 / (2.89e-4·(2.325e-3)²) = 128022 W/m² = 12.8022 W/cm²: above the
    # after-image line (3.59e-5/ω² = 6.641), below the burn line (0.118/ω = 50.75) -> yellow
    sun = _png(tmp_path / "sun.png", camera.expose(camera.sun_rate(DNI, T_SUN), T_EXP, rng))
    spot = disc_renderer(camera.shape, (70.4, 120.2), 10.0, u=0.0)
    glint = _png(
        tmp_path / "glint.png", camera.expose(camera.k * 4e-3 * 100.0 * spot / spot.sum(), T_EXP, rng)
    )
    code, res = _run(
        capsys,
        [
            "glare",
            "--sun",
            sun,
            "--source",
            glint,
            "--dni",
            str(DNI),
            "--sun-transmittance",
            str(T_SUN),
            "--source-transmittance",
            "4e-3",
            "--json",
        ],
    )
    assert code == 0
    assert res["subtended_angle_mrad"] == pytest.approx(2.325, rel=0.03)
    assert res["corneal_irradiance_w_m2"] == pytest.approx(100.0, rel=0.03)
    assert res["retinal_irradiance_w_cm2"] == pytest.approx(12.8022, rel=0.08)
    assert res["zone"] == "yellow"


def test_glare_geometry_curve(capsys, tmp_path):
    code, res = _run(
        capsys,
        [
            "glare",
            "--geometry",
            "heliostat",
            "--mirror-area-m2",
            "40",
            "--dni",
            "1000",
            "--slope-error-mrad",
            "2",
            "--distance-range",
            "10",
            "5000",
            "--points",
            "60",
            "--json",
            "--png",
            str(tmp_path / "curve.png"),
        ],
    )
    assert code == 0
    assert len(res["curve"]) == 60
    assert set(res["curve"][0]) == {
        "distance_m",
        "corneal_irradiance_w_m2",
        "retinal_irradiance_w_cm2",
        "subtended_angle_mrad",
        "zone",
    }
    # see test_glare: E_r = 2.08106 W/cm² everywhere, after-image line crossed at ω = 4.15341 mrad
    assert [r["zone"] for r in res["zone_ranges"]] == ["yellow", "green"]
    for p in res["curve"]:
        assert p["zone"] == ("yellow" if p["subtended_angle_mrad"] > 4.15341 else "green")
    assert cv2.imread(str(tmp_path / "curve.png")) is not None


@pytest.mark.parametrize(
    "argv, words",
    [
        (["glare", "--corneal-irradiance-w-m2", "10", "--geometry", "heliostat", "--json"], "exactly one"),
        (
            ["glare", "--geometry", "heliostat", "--mirror-area-m2", "40", "--dni", "1000", "--json"],
            "--distance-range",
        ),
        (["glare", "--corneal-irradiance-w-m2", "10", "--json"], "--subtended-angle-mrad"),
        (["glare", "--corneal-irradiance-w-m2", "10", "--subtended-angle-mrad", "-1", "--json"],
         "-1 is outside (0, 1000]"),
        (["glare", "--sun", "x.png", "--json"], "--source"),
    ],
)
def test_glare_bad_input_exits_2(capsys, argv, words):
    code, res = _run(capsys, argv)
    assert code == 2 and res["ok"] is False and words in res["error"]


def test_glare_saturated_source_is_refused(capsys, tmp_path, camera, rng, disc_renderer):
    sun = _png(tmp_path / "sun.png", camera.expose(camera.sun_rate(DNI, T_SUN), T_EXP, rng))
    spot = disc_renderer(camera.shape, (70.4, 120.2), 10.0, u=0.0)
    glint = _png(
        tmp_path / "glint.png", camera.expose(camera.k * 1e-2 * 400.0 * spot / spot.sum(), T_EXP, rng)
    )
    code, res = _run(capsys, ["glare", "--sun", sun, "--source", glint, "--dni", "900", "--json"])
    assert code == 2 and "saturated" in res["error"]


def test_known_beam_power_calibrates_reflectivity(capsys, tmp_path, scene):
    # The scene's target has ρ = 0.85; run with a wrong ρ = 0.5 and the beam's known power.
    files, _, power = scene
    argv = _flux_argv(
        files, tmp_path, "--distance", "100", "--view-angle-deg", "30", "--known-power-w", str(power)
    )
    argv[argv.index("--reflectivity") + 1] = "0.5"
    code, res = _run(capsys, argv)
    assert code == 0
    assert res["reflectivity_calibrated"] == pytest.approx(RHO, rel=0.02)


def test_tube_panel_total_power(capsys, tmp_path, camera, rng):
    # 4 touching tubes of radius 12 px at 100 m, 500 kW/m² on every visible surface element:
    # power = 500e3 · 4 · (π R_m) · L with R_m = 100·tan(4.65 mrad)·12/40, L = 160 px · 100·IFOV
    radius, axes = 12.0, 30.5 + 12.0 + 24.0 * np.arange(4)
    xx, yy = camera.grid()
    nearest = axes[np.argmin(np.abs(xx[..., None] - axes), axis=-1)]
    lit = (np.abs(xx - nearest) < radius) & (yy > 19.5) & (yy < 179.5)
    rate = camera.k * RHO * camera.bin(np.where(lit, 500e3, 0.0)) / np.pi * camera.omega_px
    rx = _png(tmp_path / "tubes.png", camera.expose(rate, T_EXP, rng))
    amb = _png(tmp_path / "tubes_off.png", camera.expose(0 * rate, T_EXP, rng))
    sun = _png(tmp_path / "sun.png", camera.expose(camera.sun_rate(DNI, T_SUN), T_EXP, rng))
    argv = [
        "flux",
        rx,
        "--sun",
        sun,
        "--ambient",
        amb,
        "--dni",
        str(DNI),
        "--reflectivity",
        str(RHO),
        "--sun-transmittance",
        str(T_SUN),
        "--distance",
        "100",
        "--tube-axes-px",
        *map(str, axes),
        "--tube-radius-px",
        "12",
        "--out",
        str(tmp_path / "f.npy"),
        "--json",
    ]
    code, res = _run(capsys, argv)
    assert code == 0
    r_m = 100.0 * np.tan(4.65e-3) * 12.0 / 40.0
    length = 160 * 100.0 * np.tan(4.65e-3) / 40.0
    assert res["total_power_w"] == pytest.approx(500e3 * 4 * np.pi * r_m * length, rel=0.01)


REAL = Path(__file__).resolve().parents[1] / "data" / "real" / "paint"


@pytest.mark.parametrize(
    "sun, words",
    [
        ("106293-raw.png", "no sun disc"),  # a real tower-target camera frame has no sun disc
        ("106293-flux.png", "saturated"),  # the UTIS flux estimate is scaled to 255 at its peak
    ],
)
def test_real_images_are_refused_as_sun_images(capsys, tmp_path, sun, words):
    receiver = str(REAL / "106293-cropped.png") if sun != "106293-raw.png" else str(REAL / sun)
    argv = ["flux", receiver, "--sun", str(REAL / sun), "--dni", "900", "--reflectivity", "0.9"]
    code, res = _run(capsys, [*argv, "--out", str(tmp_path / "f.npy"), "--json"])
    assert code == 2 and words in res["error"] and sun in res["error"]
    assert not (tmp_path / "f.npy").exists()


def test_documented_examples_run(capsys, tmp_path):
    """docs/flux.md and docs/glare.md run their examples on docs/examples/."""
    ex = Path(__file__).resolve().parents[2] / "docs" / "examples"
    code, out = _run(capsys, ["flux", str(ex / "rx.png"), "--sun", str(ex / "sun.png"), "--ambient",
                                 str(ex / "amb.png"), "--dni", "900", "--reflectivity", "0.85",
                                 "--sun-transmittance", "0.01", "--distance", "100", "--view-angle-deg", "30",
                                 "--out", str(tmp_path / "flux.npy"), "--png", str(tmp_path / "flux.png"),
                                 "--json"])
    assert code == 0 and out["total_power_w"] == pytest.approx(556.06e3, rel=0.01)
    code, out = _run(capsys, ["glare", "--sun", str(ex / "sun.png"), "--source", str(ex / "rx.png"),
                                 "--dni", "900", "--sun-transmittance", "0.01", "--json"])
    assert code == 0 and out["zone"] == "green"
