"""Camera registration against the simulated plant's true camera (simplant.perspective).

The plant camera sees the target through a perspective camera whose pose differs from the
nominal one the controller is told (a few mrad, a few cm), with lens distortion and the HIGH
sensor misregistered against LOW (0.3 px, 0.5 mrad). The controller registers each sensor on
a fiducial frame (controller.calibration.cycle.registration_step); these tests hold the result
against the simulator's true camera, which the controller never reads.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from controller.calibration.cycle.beam_chain import BeamChain
from controller.calibration.cycle.registration_step import (
    CameraRegistration,
    RegistrationError,
    nominal_camera,
    register_camera,
)
from controller.imaging.beam import analyze
from controller.imaging.fiducials import rectify_sensor
from controller.imaging.registration import Registration, rectification_maps
from simplant.devices.plant_camera import PlantCamera
from simplant.plant import SimulatedPlant, load_config_data
from tests.calibration.conftest import REPO

SPOT_ENU = np.array([1.3, 0.0, 31.1])  # on the target plane (y = 0), off centre
SPOT_SIGMA_M = 0.12


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """The demo plant's camera at full size, the spot scene swapped for a known Gaussian beam
    (peak 1.6x HIGH's full scale: HIGH clips in the core)."""
    data = load_config_data(REPO / "configs" / "demo.yaml")
    plant = SimulatedPlant(data, tmp_path_factory.mktemp("plant"), heliostat_ids=["H01"], seed=5)
    cam = PlantCamera(plant, plant.cfg, seed=5, perspective=True)
    plant.camera = plant.cameras[plant.cfg.calibration.target] = cam
    g = cam.grid
    rows, cols = g.shape
    yy, xx = np.mgrid[0:rows, 0:cols]
    rel = SPOT_ENU - g.center
    x0 = (rel @ g.u_axis + g.width_m / 2) / (g.width_m / cols) - 0.5
    y0 = (rel @ g.v_axis + g.height_m / 2) / (g.height_m / rows) - 0.5
    s = SPOT_SIGMA_M / (g.width_m / cols)
    spot = np.exp(-((xx - x0) ** 2 + (yy - y0) ** 2) / (2 * s * s))
    plant.scene = lambda grid, rng: spot / cam.counts_per_s * _peak_counts(plant.cfg)
    chain = BeamChain(plant.cfg)
    chain.registration = register_camera(plant.cfg, cam, plant.set_fiducials, chain.frame)
    return plant, cam, chain


def _peak_counts(cfg) -> float:
    c = cfg.camera
    return 1.6 * ((1 << c.bit_depth) - 1 - c.dark_offset_counts) / c.sensors[1].exposure_s


def _target_points() -> np.ndarray:
    x, z = np.meshgrid(np.linspace(-3.8, 3.8, 9), np.linspace(26.7, 33.3, 7))
    return np.column_stack([x.ravel(), np.zeros(x.size), z.ravel()])


def _rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def test_registration_recovers_each_sensors_true_camera_within_a_tenth_of_a_pixel(sim):
    plant, cam, chain = sim
    reg = chain.registration
    truth = cam.view.truth
    pts = _target_points()
    nominal = nominal_camera(plant.cfg)
    for sensor, r in enumerate((reg.low, reg.high)):
        assert r.rms_px < 0.1  # against the detected fiducials
        assert _rms(r.model.project(pts), truth.project(pts, sensor)) < 0.1  # against the truth
        assert _rms(nominal.project(pts), truth.project(pts, sensor)) > 5.0  # there was an error
    # The sensors' misregistration is resolved: HIGH's registered model differs from LOW's by
    # what the simulator put between them, to within the same tenth of a pixel.
    moved = _rms(reg.high.model.project(pts), reg.low.model.project(pts))
    assert abs(moved - _rms(truth.project(pts, 1), truth.project(pts, 0))) < 0.1
    assert reg.found == len(plant.cfg.camera.registration.fiducials_enu_m)
    assert set(reg.to_json()) == {"fiducials", "low", "high"}


def _centroid_error_m(chain: BeamChain, frame) -> float:
    o = chain.analyze(chain.merge(frame))
    return float(np.linalg.norm(np.asarray(o.centroid_enu) - SPOT_ENU))


def test_the_registration_is_what_puts_the_beam_centroid_right(sim):
    """Twin: the same frame through the registered chain, through the nominal camera model,
    and with no rectification at all (the pre-registration chain)."""
    plant, cam, chain = sim
    frame = cam.capture()
    registered = _centroid_error_m(chain, frame)
    nominal = BeamChain(plant.cfg)
    model = nominal_camera(plant.cfg)
    fake = Registration(model, 0.0, np.zeros((0, 2)), "pose")
    nominal.registration = CameraRegistration.build(fake, fake, nominal.frame, 0, plant.cfg.camera.bit_depth)
    unrectified = _centroid_error_m(BeamChain(plant.cfg), frame)
    assert registered < 0.005  # m on the target: 0.05 mrad from a heliostat 100 m away
    assert _centroid_error_m(nominal, frame) > 10 * registered + 0.05
    assert unrectified > 10 * registered + 0.05


def _disagreement(cam, frame, low, high) -> float:
    """Relative spread of HIGH's radiance over LOW's (true CRFs) where both measure the spot
    (neither clipped nor near dark): the edge artefact an HDR merge of a misregistered pair
    would get, a dipole along every gradient of the spot."""
    crf, t = cam.true_crf(), frame.exposures
    both = (high > 30) & (high < 235) & (low > 30)
    assert both.sum() > 1000  # the spot's flanks
    ratio = (crf.inverse(1)[high[both]] / t[1]) / (crf.inverse(0)[low[both]] / t[0])
    return float(np.std(ratio / np.median(ratio)))


def test_a_misregistered_clipped_pair_merges_without_edge_artefacts(sim):
    """Each sensor rectified through its own registration: on the spot's flanks the two
    sensors agree to their noise, and the merged spot follows the true one. The twin (HIGH
    rectified through LOW's registration, the sensors' 0.3 px misregistration left in) shows
    the artefact the per-sensor registration removes."""
    plant, cam, chain = sim
    frame = cam.capture()
    full = (1 << plant.cfg.camera.bit_depth) - 1
    assert frame.high.max() == full  # HIGH clips the core
    low, high = chain.registration.rectify(frame)
    good = _disagreement(cam, frame, low, high)
    low_maps = rectification_maps(chain.registration.low.model, chain.frame)
    same_model = rectify_sensor(frame.high, low_maps, full)
    bad = _disagreement(cam, frame, low, same_model)
    assert good < 0.035
    assert bad > 1.6 * good
    hdr = chain.merge(frame)
    truth = plant.scene(cam.grid, None) * cam.counts_per_s
    inside = truth > 0.05 * truth.max()
    sig = hdr - analyze(hdr).background.level
    scale = float(np.sum(sig[inside] * truth[inside]) / np.sum(truth[inside] ** 2))
    resid = (sig[inside] / scale - truth[inside]) / truth.max()
    assert float(np.sqrt(np.mean(resid**2))) < 0.03  # no ring at the clipped core's rim either


def test_no_fiducials_lit_is_refused_with_a_clear_error(sim):
    plant, cam, chain = sim
    with pytest.raises(RegistrationError, match="fiducials within .* px of their nominal pixels"):
        register_camera(plant.cfg, cam, lambda on: None, chain.frame)


def test_a_registration_above_the_rms_bound_is_refused(sim, tmp_path):
    plant, cam, chain = sim
    data = yaml.safe_load(yaml.safe_dump(plant.data))
    # A surveyed fiducial 15 cm off: the fit cannot reproject it within 0.5 px.
    data["camera"]["registration"]["fiducials_enu_m"][0][0] += 0.15
    from controller.config import parse_config

    cfg = parse_config(data, "p.yaml")
    with pytest.raises(RegistrationError, match=r"LOW sensor refused: .*RMS .* exceeds 0.5 px"):
        register_camera(cfg, cam, plant.set_fiducials, chain.frame)
