"""Fixtures for the calibration state machine and campaign tests.

``make_cycle`` builds one :class:`CalibrationCycle` over a :class:`SimController` behind a
:class:`SimDrive` (the Drive interface without a wire, for fast fault injection), a camera
whose "image" is the true beam offset, and a linear pointing model whose Jacobian is exact:
the beam lands ``A @ (true_steps - ideal_steps)`` metres from the aim point, with the true steps
being the rods' positions (backlash included) plus a hidden offset.

Faults are injected from callbacks, never after a delay: ``SimDrive.after`` hooks run after
every drive call (``hook(call_name, drive)``), and ``Plant.on_state`` hooks run on every state
change of the cycle (``hook(state)``), on the cycle's own thread.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
import yaml

from controller.calibration.cycle.context import CycleContext, CycleObserver
from controller.calibration.cycle.gate import TargetGate
from controller.calibration.cycle.machine import CalibrationCycle
from controller.calibration.cycle.observations import Observation, Step
from controller.calibration.records import ModelRecord
from controller.devices.camera import CameraError, FramePair
from controller.devices.drive import Drive, DriveLimits, DriveStatus, FirmwareInfo, LinkError, NakError
from controller.devices.plant_time import PlantTime
from firmware_proto.faults import Reject, fault_names
from simplant.clock import PlantClock
from simplant.firmware.physics import AxisParams, SimController
from simplant.settings import SimulationSettings
from tests.conftest import scaled_s

SPEEDUP = 200.0
FAST = SimulationSettings(clock_speedup=50.0)  # simulated-plant settings of the campaign tests
AIM = np.array([0.0, 0.0, 30.0])
HELIOSTAT = np.array([0.0, 50.0, 0.0])  # 58.3 m from the aim point
# metres on the target per motor step: east per az step, up per el step (about 0.4 mrad/100 steps)
A = np.array([[2.0e-4, 0.0], [0.0, 2.5e-4]])


class SimDrive(Drive):
    """The Drive interface straight onto a SimController; ``link_lost`` makes every call fail."""

    def __init__(self, ctl: SimController, limits: DriveLimits) -> None:
        self.ctl = ctl
        self.unit = ctl.unit
        self.limits = limits
        self.link_lost = False
        self.calls: list[str] = []
        self.after: list = []  # hook(call_name, drive) after every successful call

    def _check(self, what: str) -> None:
        self.calls.append(what)
        if self.link_lost:
            raise LinkError(f"unit {self.unit}: no answer to {what} after 3 retries (link down)")

    def _done(self, what: str) -> None:
        for hook in list(self.after):
            hook(what, self)

    def _ok(self, r: Reject, what: str) -> None:
        if r != Reject.OK:
            raise NakError(f"unit {self.unit}: {what} refused ({r.name})", int(r))

    def status(self) -> DriveStatus:
        self._check("status")
        s = self.ctl.status()
        st = DriveStatus(self.unit, s["az_steps"], s["el_steps"], s["az_target"], s["el_target"],
                         s["moving"], s["in_position"], s["limit_az"], s["limit_el"],
                         tuple(fault_names(s["faults"])))
        self._done("status")
        return st

    def _send_move_abs(self, az, el):
        self._check("move")
        self._ok(self.ctl.move_abs(az, el), "MOVE_ABS")
        self._done("move")

    def _send_jog(self, daz, delv):
        self._check("jog")
        self._ok(self.ctl.jog(daz, delv), "JOG")

    def stop(self):
        self._check("stop")
        self.ctl.stop()

    def home(self):
        self._check("home")
        self._ok(self.ctl.home(), "HOME")

    def stow(self):
        self._check("stow")
        self._ok(self.ctl.stow(), "STOW")

    def clear_fault(self):
        self._check("clear_fault")
        self.ctl.clear_fault()

    def info(self) -> FirmwareInfo:
        return FirmwareInfo(1, 2, self.limits, "sim-drive")

    def get_limits(self) -> DriveLimits:
        return self.limits

    def set_limits(self, limits: DriveLimits) -> None:
        self._check("set_limits")
        self.limits = limits

    def close(self):
        pass


@dataclass
class Plant:
    """One heliostat of the fake plant: controller, hidden offset, camera state."""

    ctl: SimController
    clock: PlantClock
    hidden_steps: np.ndarray
    ideal: tuple[int, int] = (30000, 30000)
    standby: tuple[int, int] = (25000, 30000)
    camera_fail: int = 0
    camera_block: threading.Event | None = None  # capture waits until it is set
    noise_m: float = 0.0
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))
    captures: int = 0
    true_errors: list[float] = field(default_factory=list)  # at every measurement, mrad
    on_state: list = field(default_factory=list)  # hook(state) on every state change

    def offset(self) -> np.ndarray:
        """True beam offset from the aim point, m (east, up)."""
        out = np.array(self.ctl.output_steps()) + self.hidden_steps
        return A @ (out - np.array(self.ideal))

    def true_error_mrad(self) -> float:
        d = self.offset()
        spot = AIM + np.array([d[0], 0.0, d[1]])
        a, b = AIM - HELIOSTAT, spot - HELIOSTAT
        return float(1e3 * np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))


class FakeCamera:
    def __init__(self, plant: Plant) -> None:
        self.p = plant

    def capture(self) -> FramePair:
        if self.p.camera_block is not None:
            self.p.camera_block.wait(scaled_s(10.0))
        if self.p.camera_fail > 0:
            self.p.camera_fail -= 1
            raise CameraError("camera: no frame from ccd2 within 2 s")
        self.p.captures += 1
        d = self.p.offset() + self.p.rng.normal(0, self.p.noise_m, 2)
        z = np.zeros((4, 4), np.uint8)
        return FramePair(z, z, (0.01, 0.02), self.p.clock(), {"offset": d})


class LinearPointing:
    def __init__(self, plant: Plant) -> None:
        self.p = plant
        self.heliostat_pos = HELIOSTAT
        self.aim_point = AIM
        self.source_dir = np.array([0.0, -0.6, 0.8])
        self.source_pos = None  # the sun
        self.fits = 0

    def aim_steps(self, model):
        shift = np.zeros(2) if model is None else np.array(model.params["steps"])
        return tuple(int(v) for v in np.array(self.p.ideal) + shift)

    def standby_steps(self, model):
        return self.p.standby

    def leave_steps(self, model, seen=None):  # one standby: the fake plant's park
        return self.p.standby

    def path_to(self, start, end):
        return [end]

    def stay_margin_m(self) -> float:
        return 2.0

    def may_wait_at(self, pose, standby, aim, margin_m) -> bool:
        return False  # the fake plant's heliostat always parks at standby first

    def beam_on_target(self, az, el, margin_m: float = 2.0) -> bool:
        """The true beam within 3 m (plus the margin) of the aim point."""
        out = np.array((az, el), float) + self.p.hidden_steps - np.array(self.p.ideal)
        return bool(np.all(np.abs(A @ out) <= 3.0 + margin_m))

    def view_margin_m(self) -> float:
        return 2.0

    def path_margin_m(self) -> float:
        return 2.5

    def off_targets(self, az, el, margin_m: float = 2.0) -> bool:
        """The one target of the fake plant; no person zone."""
        return not self.beam_on_target(az, el, margin_m)

    def fine_correction(self, az, el, offset_enu):
        d = np.linalg.solve(A, -np.array([offset_enu[0], offset_enu[2]]))
        return Step(float(d[0]) * 1e-3, float(d[1]) * 1e-3, int(round(d[0])), int(round(d[1])))

    def coarse_correction(self, az, el, daz_deg, del_deg):
        return Step(daz_deg, del_deg, int(daz_deg * 1000), int(del_deg * 1000))

    def fit(self, measurements, prior):
        self.fits += 1
        m = measurements[-1]
        off = np.array([m.centroid_enu[0] - AIM[0], m.centroid_enu[2] - AIM[2]])
        shift = np.linalg.solve(A, off) + (np.array([m.az_steps, m.el_steps]) - np.array(self.p.ideal))
        return ModelRecord({"steps": shift.tolist()}, {}, 0.0, len(measurements))


def _observe(frame) -> Observation:
    d = frame.metadata["offset"]
    c = AIM + np.array([d[0], 0.0, d[1]])
    return Observation((0.0, 0.0), tuple(c), np.ones(7), 1.0)


class PlantTruth(CycleObserver):
    """The fake plant's side of the cycle: its true error at each measurement, and the
    per-state fault hooks of the test."""

    def __init__(self, plant: Plant) -> None:
        self.p = plant

    def state_changed(self, heliostat_id: str, state: str) -> None:
        for hook in list(self.p.on_state):
            hook(state)

    def measured(self, heliostat_id: str, measurement) -> None:
        self.p.true_errors.append(self.p.true_error_mrad())


@pytest.fixture
def make_cycle():
    made: list[Plant] = []

    def make(*, hidden=(150, -90), backlash=0, gate=None, ticket=0, match=None, timeouts=None,
             max_iterations=4, tolerance_mrad=0.3, initial=(25000, 30000), model=None, clock=None):
        clock = clock or PlantClock(SPEEDUP)
        ax = AxisParams(500, 60000, 0, 65000, speed=1500, acceleration=3000, backlash=backlash)
        ctl = SimController(1, ax, AxisParams(**{**ax.__dict__}), clock=clock, initial_steps=initial)
        plant = Plant(ctl, clock, np.array(hidden, float))
        drive = SimDrive(ctl, DriveLimits.from_axes(_Axes()))
        pointing = LinearPointing(plant)
        ctx = CycleContext(
            heliostat_id="H1", queue_index=0, ticket=ticket, drive=drive, camera=FakeCamera(plant),
            pointing=pointing, merge=lambda frame: frame, analyze=_observe,
            match=lambda hu: match, gate=gate or TargetGate(), model=model, tolerance_mrad=tolerance_mrad,
            max_iterations=max_iterations, settle_s=0.2,
            time=PlantTime(now=clock, sleep=clock.sleep, poll_s=0.05),
            timeouts=timeouts or {}, observer=PlantTruth(plant), move_timeout_s=scaled_s(60.0))
        made.append(plant)
        return CalibrationCycle(ctx), plant, drive

    return make


class _Lim:
    def __init__(self, lo, hi):
        self.min_steps, self.max_steps = lo, hi


class _Axis:
    def __init__(self):
        self.soft_limits = _Lim(500, 60000)


class _Axes:
    azimuth = _Axis()
    elevation = _Axis()


REPO = Path(__file__).resolve().parents[2]


def small_demo_data() -> dict:
    """The demo plant's configuration document with 256×192 cameras, to keep tests quick."""
    data = yaml.safe_load((REPO / "configs" / "demo.yaml").read_text())
    for cam in [data["camera"]] + [t["camera"] for t in data["targets"] if t.get("camera")]:
        cam["width_px"], cam["height_px"] = 256, 192
        reg = cam.get("registration")
        if reg:  # the same lens on a 4x binned sensor: a quarter of the focal length in pixels
            reg["focal_px"] = reg["focal_px"] * 256 / 1024
    return data


@pytest.fixture
def small_config(tmp_path) -> Path:
    """The demo plant with 256×192 cameras (:func:`small_demo_data`; run it with :data:`FAST`)."""
    p = tmp_path / "small.yaml"
    p.write_text(yaml.safe_dump(small_demo_data()))
    return p


def calibrated_record(cfg, hid: str, observations: int = 3) -> ModelRecord:
    """The model record of ``hid`` as a closed-loop calibration leaves it: the nominal model
    with the prior covariance updated by ``observations`` measurements at the calibration lamp
    and the calibration target's centre (Eq. 1 of controller.geometry.design)."""
    from controller.calibration.night.daytime import model_covariance
    from controller.geometry.design import normal_jacobian, posterior
    from controller.geometry.kinematics import HeliostatKinematics
    from controller.geometry.model.tracking import model_aim

    cal = cfg.calibration
    model, cov = model_covariance(None, cal.model)
    kin = HeliostatKinematics.from_config(cfg.heliostat(hid))
    lamp = np.asarray(cfg.light_source().position_enu_m, float)
    centre = np.asarray(cfg.target().center_enu_m, float)
    steps = model_aim(kin, model, None, centre, lamp_position=lamp)
    for _ in range(observations):
        h = normal_jacobian(kin, model, *steps, None, centre, lamp)
        cov = posterior(cov, h, cal.model.noise_mrad * 1e-3)
    return ModelRecord(model.to_dict(), {}, 0.2, observations, {"covariance_si": cov.tolist()})
