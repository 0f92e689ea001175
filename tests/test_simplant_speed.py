"""The simulated plant's speed-ups leave its truth unchanged: the same numbers, to the bit,
as the formulas they replaced (kept as the peer of ``benchmarks/bench_sim_speed.py``), and the
same beams on the same targets."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import controller
from simplant.hidden import mean_slope
from simplant.plant import SimulatedPlant, load_config_data
from simplant.poses import true_pose
from simplant.truth import draw_truth

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_sim_speed import previous_normal, previous_sample  # noqa: E402

DEMO = Path(controller.__file__).parent / "data" / "demo.yaml"
AXIS = {"increment": 154166.6667, "initial_stroke_length": 0.0775, "offset": 0.3408, "pivot_radius": 0.3191,
        "initial_angle": 0.9439, "clockwise_axis_movement": True}


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_truth_normal_and_centre_are_bitwise_the_original_formulas(seed):
    rng = np.random.default_rng(seed)
    t = draw_truth([10.0, 60.0, 0.0], AXIS, {**AXIS, "clockwise_axis_movement": False}, [0.0, 0.1, 0.05], rng,
                   scale=2.0)
    for _ in range(50):
        az, el = rng.uniform(500, 70000, 2)
        night = int(rng.integers(0, 5))
        jitter = tuple(rng.normal(0.0, 1e-4, 2)) if rng.random() < 0.5 else None
        n, _ = previous_normal(t, az, el, night, jitter)
        _, centre = previous_normal(t, az, el, night, None)
        assert np.array_equal(t.normal(az, el, night=night, jitter=jitter), n)
        assert np.array_equal(t.mirror_center(az, el, night=night), centre)


@pytest.fixture
def plant(tmp_path):
    return SimulatedPlant(load_config_data(DEMO), tmp_path / "plant", source=str(DEMO))


def settle_all(plant: SimulatedPlant, rng: np.random.Generator) -> None:
    """Send every heliostat to a random pose and let plant time run until all stand still."""
    for hh in plant.hidden.values():
        hh.controller.move_abs(int(rng.integers(20000, 50000)), int(rng.integers(20000, 50000)))
    with plant.clock.frozen(advance_s=1000.0):
        pass


def test_true_pose_is_true_normal_and_centre_and_follows_moves_and_nights(plant):
    rng = np.random.default_rng(3)
    for night in (0, 2, 3):  # night 3 without a move: the drift alone changes the pose
        plant.set_night(night)
        if night != 3:
            settle_all(plant, rng)
        for hid, hh in plant.hidden.items():
            n, c = true_pose(plant, hid)
            steps = hh.controller.output_steps()
            assert np.array_equal(n, plant.true_normal(hid))
            assert np.array_equal(c, hh.truth.mirror_center(*steps, night=night))
            assert true_pose(plant, hid)[0] is n  # standing still: kept, not recomputed


def test_safety_monitor_sees_the_same_beams_on_every_target(plant):
    rng = np.random.default_rng(4)
    aimed = 0
    for _ in range(4):
        settle_all(plant, rng)
        # Aim a few heliostats at a target so that the check is not only about empty targets.
        for hid in list(plant.hidden)[:3]:
            hh = plant.hidden[hid]
            hh.controller.move_abs(*_aim_steps(plant, hid, plant.cfg.targets[aimed % 2].id))
            aimed += 1
        with plant.clock.frozen(advance_s=1000.0):
            pass
        beams, previous = plant.safety.beams(), previous_sample(plant)
        for t in plant.cfg.targets:
            assert plant.safety.on_target(t.id, beams) == previous[t.id]
    assert any(plant.safety.on_target(t.id) for t in plant.cfg.targets)


def _aim_steps(plant: SimulatedPlant, hid: str, target: str) -> tuple[int, int]:
    from controller.geometry.nominal_aim import nominal_aims

    cfg = plant.cfg.for_target(target)
    return next((a.az_steps, a.el_steps) for a in nominal_aims(cfg, [hid]))


def test_mean_slope_kept_per_mirror(plant):
    for hh in plant.hidden.values():
        assert hh.mean_slope == mean_slope(hh.mirror)


@pytest.mark.parametrize("target", ["tower-target", "tower-lower"])
def test_perspective_tables_from_the_lattice_match_every_pixel_traced(target):
    from controller.config import load_config
    from simplant.devices.grids import camera_grid
    from simplant.perspective import PerspectiveView, true_camera

    cfg = load_config(DEMO).for_target(target)
    view = PerspectiveView(true_camera(cfg, 0), camera_grid(cfg))
    for sensor in (0, 1):
        exact = view.grid_coords(sensor, 1)
        assert exact[0].shape == (cfg.camera.height_px, cfg.camera.width_px)
        for table, full in zip(view.maps[sensor], exact, strict=True):
            assert np.abs(table - full).max() < 0.005  # grid px; the spot spans hundreds
            assert np.ptp(full) > 500  # the tables are not trivially flat
