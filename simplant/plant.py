"""The embedded simulated plant behind ``heliocal demo`` (and the campaign tests).

What it runs, all in this process but reachable only through the real wire protocols:

* one :class:`simplant.firmware.physics.SimController` per heliostat, on a **plant clock**
  (:class:`PlantClock`) that may run ``SimulationSettings.clock_speedup`` times faster than real time;
* its drives on their wires (:mod:`simplant.devices.plant_drives`): per serial bus of the config,
  :class:`simplant.firmware.serial.SerialSimFirmware` on a pty,
  symlinked inside the run directory (the config's device paths are rewritten to it);
* the Modbus TCP heliostats behind :class:`simplant.firmware.modbus.ModbusSimServer` on
  127.0.0.1, an ephemeral port (written back into the links); Modbus RTU on a pty;
* the lamp panel (:class:`simplant.devices.lamp_panel.SimLampPanel`) on 127.0.0.1, an ephemeral port
  (written into the config as its ``lamps:`` section): its coils switch the lamps the plant
  renders with, its discrete inputs report them;
* a hidden heliostat per id (:mod:`simplant.truth`, written independently of the controller's
  kinematics and error model: perturbed actuators, pedestal, joints, canting, position, gravity
  droop, nightly drift, per-move repeatability; seeded, angular errors scaled by
  ``tracking_error_mrad``/3) and an injected error *case* from the error set (its mirror
  shape: deformation, focus, wind rocking, and its own pointing), so that the morning report
  can score the Hu-moment recognition against the truth;
* a simulated double-CCD camera (:class:`PlantCamera`) per target, looking at it under the lamp
  (``cameras``, by target id; ``camera`` is the calibration target's).
  Its scene is the sum of the beams of every heliostat whose reflected central ray lands
  within the view (plus margin), each ray traced from the TRUE normal: the hidden heliostat
  at the rods' true positions (``SimController.output_steps``, backlash included).

The plant clock stands still while the simulator renders a scene (that is the simulator's
work, not the plant's) and advances by the exposure time instead; the controller's own image
processing runs on the plant clock like everything else.

Truth for the report: the reflected-beam pointing error of a heliostat, i.e. the angle
between the reflection of the lamp direction about its true normal at the mirror centre and
the direction from the mirror centre to the calibration target's centre, in mrad.
"""

from __future__ import annotations

import copy
from dataclasses import replace
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import yaml

from controller.config import PlantConfig, parse_config
from controller.errors import ConfigError
from controller.field_file import field_path
from controller.geometry.vectors import unit
from simplant.clock import PlantClock
from simplant.devices.grids import camera_grid, coarse_grid
from simplant.devices.plant_camera import RENDER_RAYS, PlantCamera
from simplant.errorset import CASES
from simplant.firmware.physics import SimController, axis_params_from_config
from simplant.hidden import HiddenHeliostat
from simplant.optics import MirrorSurface, TargetGrid, render_spot
from simplant.poses import true_pose
from simplant.safety import BeamSafetyMonitor
from simplant.settings import SimulationSettings
from simplant.spot_truth import SpotTruth
from simplant.truth import HIDDEN_ERRORS, hidden_truth

NIGHT_ONE = datetime(2026, 3, 1, 20, 0, tzinfo=UTC)  # first simulated night, plant calendar
TRUTH_RAYS = 100_000
# A worn gear rocks across its dead band when gusts push the mirror (the error set renders the
# full band). Calibration nights are calm: the plant lets the mirror sweep this fraction of it.
NIGHT_ROCK_FRACTION = 0.1


def field_selection(cfg: PlantConfig, n: int) -> list[str]:
    """``n`` heliostat ids, taken round-robin over the links (bus/connection) in config order,
    so that a small demo still exercises every link of the field."""
    groups: dict[tuple, list[str]] = {}
    for h in cfg.heliostats:
        link = h.link
        groups.setdefault(link.bus_key, []).append(h.id)
    out: list[str] = []
    lists = list(groups.values())
    while len(out) < min(n, len(cfg.heliostats)):
        for g in lists:
            if g and len(out) < n:
                out.append(g.pop(0))
    order = {h.id: i for i, h in enumerate(cfg.heliostats)}
    return sorted(out, key=order.__getitem__)


class SimulatedPlant:
    """Start with :meth:`start` (returns the rewritten config), stop with :meth:`stop`."""

    def __init__(self, cfg_data: dict, run_dir: str | Path, *, heliostat_ids: list[str] | None = None,
                 settings: SimulationSettings | None = None, seed: int | None = None, cases: int = 6,
                 source: str = "<config>", clock_start: float = 0.0) -> None:
        self.run_dir = Path(run_dir)
        self.data = copy.deepcopy(cfg_data)
        if self.data.get("field"):  # the field file stays where it is when the config is rewritten
            self.data["field"]["file"] = str(field_path(self.data["field"]["file"], source).absolute())
        cfg = parse_config(self.data, source)
        self.cfg = cfg
        self.ids = heliostat_ids or [h.id for h in cfg.heliostats]
        sim = settings or SimulationSettings()
        self.settings = sim
        self.seed = sim.seed if seed is None else seed
        self.clock = PlantClock(sim.clock_speedup, start=clock_start)
        self.hidden: dict[str, HiddenHeliostat] = {}
        self.night = 0
        self._lit: tuple[str, ...] = (self.cfg.calibration.light_source,)  # in the order switched on
        self.lamp_panel = None  # simplant.devices.lamp_panel.SimLampPanel, from start()
        index = {h.id: i for i, h in enumerate(cfg.heliostats)}
        for hid in self.ids:
            h = cfg.heliostat(hid)
            if h.link.kind == "none":
                raise ConfigError(f"{source}: heliostats: {hid} has link: none (records only); the simulated "
                                  "plant serves serial and Modbus links")
            # One generator per heliostat: its truth does not depend on which others are in the run.
            rng = np.random.default_rng([self.seed, 7, index[hid]])
            case = CASES[int(rng.integers(0, cases))]
            # The mirror's nominal normal at work: halfway between the calibration light and target.
            pos = np.asarray(h.position_enu_m, float)
            facing = unit(unit(np.asarray(cfg.light_source().position_enu_m, float) - pos)
                          + unit(np.asarray(cfg.target().center_enu_m, float) - pos)) \
                if getattr(cfg.light_source(), "kind", "") == "lamp" else None
            truth = hidden_truth(h, rng, sim.tracking_error_mrad / 3.0, case,
                                 HIDDEN_ERRORS[sim.hidden_errors], facing)
            mirror = replace(MirrorSurface.from_config(h.mirror), deformation=case.deformation,
                             focal_length_m=h.mirror.focal_length_m / case.focus_factor)
            ctl = SimController(unit=h.link.station,
                                az=axis_params_from_config(h.axes.azimuth),
                                el=axis_params_from_config(h.axes.elevation), clock=self.clock)
            self.hidden[hid] = HiddenHeliostat(hid, truth, case, mirror, ctl, (self.seed, 13, index[hid]))
        self._drives = None  # simplant.devices.plant_drives.Drives, from start()
        self.serial: dict[str, object] = {}  # its serial firmware by configured device
        self.modbus = None  # its Modbus server
        self.safety = BeamSafetyMonitor(self)
        self.spot_truth = SpotTruth()  # whose spot is where in each render; the identity-swap fault
        self.camera: PlantCamera | None = None  # the calibration target's camera
        self.cameras: dict[str, PlantCamera] = {}  # target id -> its camera
        self.config: PlantConfig | None = None

    # -- lifecycle -------------------------------------------------------------------------------
    def start(self) -> PlantConfig:
        """Start firmware and servers; return the config with links rewritten to them."""
        from simplant.devices.plant_drives import serve_drives

        self.run_dir.mkdir(parents=True, exist_ok=True)
        dev_dir = self.run_dir / "dev"
        dev_dir.mkdir(exist_ok=True)
        links = [(self.cfg.heliostat(hid).link, self.hidden[hid].controller) for hid in self.ids]
        drives = serve_drives(links, dev_dir)
        self._drives, self.serial, self.modbus = drives, drives.serial, drives.modbus
        # The field file's buses (field.buses), else each inline heliostat's link.
        drives.rewrite(list(self.data["field"]["buses"].values()) if self.data.get("field")
                       else [h["link"] for h in self.data["heliostats"]])
        self._start_lamp_panel()
        self.config = parse_config(self.data, str(self.run_dir / "plant.yaml"))
        self._start_cameras()
        self.safety.start()
        return self.config

    def _start_lamp_panel(self) -> None:
        """Serve the plant's lamp panel and write its ``lamps:`` section (replacing any)."""
        from simplant.devices.lamp_panel import SimLampPanel, panel_channels

        channels = panel_channels(self.cfg)
        self.lamp_panel = SimLampPanel(self, channels)
        port = self.lamp_panel.start()
        self.data["lamps"] = {"driver": "modbus-tcp", "host": "127.0.0.1", "port": port, "unit": 1,
                              "channels": channels}

    def _start_cameras(self) -> None:
        """One camera per target (seeded apart, the calibration target's with the plant seed).
        The simulated sensors are non-linear: hand the controller each camera's response, as
        an integrating-sphere calibration would (controller.imaging.crf file format)."""
        cfg = self.config
        default = cfg.calibration.target
        for k, t in enumerate(cfg.targets):
            seed = self.seed if t.id == default else self.seed + 1000 * (k + 1)
            self.cameras[t.id] = PlantCamera(self, cfg.for_target(t.id), seed=seed, perspective=True)
        self.camera = self.cameras[default]
        if not cfg.camera.crf_file:
            self.camera.true_crf().save(self.run_dir / "crf.yaml")
            self.data["camera"]["crf_file"] = str(self.run_dir / "crf.yaml")
        for t, raw in zip(cfg.targets, self.data["targets"], strict=True):
            if t.camera is not None and not t.camera.crf_file:
                path = self.run_dir / f"crf-{t.id}.yaml"
                self.cameras[t.id].true_crf().save(path)
                raw["camera"]["crf_file"] = str(path)
        self.config = parse_config(self.data, str(self.run_dir / "plant.yaml"))

    def stop(self) -> None:
        self.safety.stop()
        if self._drives is not None:
            self._drives.stop()
        self.serial, self.modbus = {}, None
        if self.lamp_panel is not None:
            self.lamp_panel.stop()

    def __enter__(self) -> SimulatedPlant:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- fault hooks (tests) -------------------------------------------------------------------------
    def serial_firmware(self, heliostat_id: str):
        return self.serial[self.cfg.heliostat(heliostat_id).link.device]

    # -- truth --------------------------------------------------------------------------------------
    def set_night(self, night: int) -> None:
        """Which night it is (0 the first): the hidden heliostats drift between nights."""
        self.night = int(night)

    def set_fiducials(self, on: bool, target: str | None = None) -> None:
        """Switch the fiducial lamps of ``target`` (None: every target's) for camera registration
        (simplant.perspective). Per target, because the targets' campaigns register in parallel:
        one target's lit fiducials must not fall into another's dark frame."""
        for tid, cam in self.cameras.items():
            if target is None or tid == target:
                cam.fiducials_lit = bool(on)

    @property
    def lit(self) -> str | None:
        """The lamp the plant renders with: the lit one (the last switched on, should a panel
        light several); None while every lamp is dark."""
        return self._lit[-1] if self._lit else None

    def lamp_lit(self, lamp_id: str) -> bool:
        return lamp_id in self._lit

    def switch_lamp(self, lamp_id: str, on: bool) -> None:
        """Switch one lamp (the lamp panel's coil), leaving the others as they are."""
        if getattr(self.cfg.light_source(lamp_id), "kind", "") != "lamp":
            raise ValueError(f"the simulated plant lights lamps only, not {lamp_id!r}")
        rest = tuple(lamp for lamp in self._lit if lamp != lamp_id)
        self._lit = (*rest, lamp_id) if on else rest

    def set_light(self, source_id: str) -> None:
        """Light lamp ``source_id`` (the others go dark): one lamp at a time, as a campaign asks."""
        if getattr(self.cfg.light_source(source_id), "kind", "") != "lamp":
            raise ValueError(f"the simulated plant lights lamps only, not {source_id!r}")
        self._lit = (source_id,)

    def lights_out(self) -> None:
        """Switch every lamp off (a night's lamp change: heliostats are moved in the dark)."""
        self._lit = ()

    def lamp(self):
        """The lamp lit now (config entry); None while every lamp is dark."""
        return None if self.lit is None else self.cfg.light_source(self.lit)

    def utc(self) -> str:
        """Plant time as an ISO 8601 UTC stamp: night k starts at 20:00 on day k of the plant's
        calendar, plus the plant clock."""
        t = NIGHT_ONE + timedelta(days=self.night, seconds=self.clock())
        return t.astimezone(UTC).isoformat(timespec="milliseconds")

    def true_normal(self, hid: str) -> np.ndarray:
        """True normal of ``hid`` at its rods' present positions (repeatability included)."""
        hh = self.hidden[hid]
        steps = hh.controller.output_steps()
        return hh.truth.normal(*steps, night=self.night, jitter=hh.settle(tuple(steps), self.night))

    def true_normal_at(self, heliostat_id: str, az_steps: float, el_steps: float) -> np.ndarray:
        """Unit ENU mirror normal of the hidden heliostat at the given motor steps (tonight's
        drift, no repeatability error), as its beam sees it (:meth:`HiddenHeliostat.beam_normal`:
        a canted facet moves the energy centroid): the plant's truth, for scoring any aim (e.g.
        ``heliocal aim`` at a sun position) independently."""
        hh = self.hidden[heliostat_id]
        return hh.beam_normal(hh.truth.normal(az_steps, el_steps, night=self.night))

    def true_mirror_center(self, heliostat_id: str, az_steps: float, el_steps: float) -> np.ndarray:
        """Centre of the hidden heliostat's mirror at the given steps, m ENU."""
        return self.hidden[heliostat_id].truth.mirror_center(az_steps, el_steps, night=self.night)

    def beam_normals(self, hid: str) -> list[np.ndarray]:
        """True normal(s) of ``hid`` now: one, or the poses a rocking (worn) gear sweeps."""
        hh = self.hidden[hid]
        if not hh.case.rock_az_rad:
            return [self.true_normal(hid)]
        steps = hh.controller.output_steps()
        j_el, j_az = hh.settle(tuple(steps), self.night)
        band = hh.case.rock_az_rad * NIGHT_ROCK_FRACTION
        return [hh.truth.normal(*steps, night=self.night, jitter=(j_el, j_az + d))
                for d in np.linspace(-0.5, 0.5, 5) * band]

    def true_error_mrad(self, hid: str) -> float:
        """Reflected-beam pointing error of ``hid`` against the target centre, mrad.

        The beam's direction is that of its energy centroid on the target plane, from a
        noise-free ray trace of the true mirror (deformation included) on a 12 m grid about
        the central ray; for an undeformed mirror this is the reflected central ray."""
        hh = self.hidden[hid]
        pos = hh.truth.mirror_center(*hh.controller.output_steps(), night=self.night)
        tgt = self.cfg.target()
        c, nrm = np.asarray(tgt.center_enu_m, float), unit(np.asarray(tgt.normal, float))
        lamp = np.asarray(self.lamp().position_enu_m, float)
        s = unit(lamp - pos)
        with self.clock.frozen():
            normals = self.beam_normals(hid)
            n = unit(np.mean(normals, axis=0))
            beam = 2.0 * (s @ n) * n - s
            hit = pos + float(nrm @ (c - pos)) / float(nrm @ beam) * beam
            base = camera_grid(self.cfg)
            # Bilinear splatting keeps every ray's first moment, so a coarse grid gives the
            # exact energy centroid of the traced rays.
            grid = TargetGrid(hit, nrm, base.u_axis, base.v_axis, 12.0, 12.0, (64, 64))
            diameter = float(self.lamp().diameter_m) / float(np.linalg.norm(lamp - pos))
            img = sum(render_spot(pos, nn, lamp, diameter, hh.mirror, grid, rng=np.random.default_rng(1),
                                  n_rays=TRUTH_RAYS // len(normals)) for nn in normals)
        yy, xx = np.mgrid[0:64, 0:64]
        tot = float(img.sum())
        spot = grid.pixel_to_enu(float((img * xx).sum() / tot), float((img * yy).sum() / tot))
        a, b = unit(spot - pos), unit(c - pos)
        return float(1e3 * np.arccos(np.clip(a @ b, -1.0, 1.0)))

    def truth_label(self, hid: str) -> str:
        return self.hidden[hid].case.label

    def _source_dir(self, pos: np.ndarray) -> np.ndarray:
        src = self.lamp()
        if getattr(src, "kind", "") == "lamp":
            return unit(np.asarray(src.position_enu_m, float) - pos)
        raise ValueError("the simulated plant renders the lamp only (nightly campaigns)")

    # -- the scene ------------------------------------------------------------------------------------
    def scene(self, grid: TargetGrid, rng: np.random.Generator) -> np.ndarray:
        """Irradiance on ``grid`` (W/m² per W/m² of lamp irradiance) of every beam in view.

        Rays are traced onto a grid of about ``RENDER_PITCH_M`` pitch (:func:`coarse_grid`)
        and the result is interpolated up to the camera's: the Monte Carlo noise per pixel of
        a large defocused spot would otherwise dwarf the sensor noise (a simulation artefact)."""
        import cv2

        src = self.lamp()
        if src is None:
            return np.zeros(grid.shape)  # every lamp dark (a lamp change)
        lamp = np.asarray(src.position_enu_m, float)
        rows, cols = grid.shape
        coarse = coarse_grid(grid)
        img = np.zeros(coarse.shape)
        half = np.array([grid.width_m, grid.height_m]) / 2 + 1.5  # margin for the spot size
        seen = {}
        for hid in self.hidden:
            n, pos = true_pose(self, hid)
            s = unit(lamp - pos)
            beam = 2.0 * (s @ n) * n - s
            denom = float(grid.normal @ beam)
            if abs(denom) < 1e-9:
                continue
            t = float(grid.normal @ (grid.center - pos)) / denom
            if t <= 0:
                continue
            rel = pos + t * beam - grid.center
            if abs(rel @ grid.u_axis) > half[0] or abs(rel @ grid.v_axis) > half[1]:
                continue
            seen[hid] = (pos, rel)
        shifts = self.spot_truth.shifts({hid: rel for hid, (_, rel) in seen.items()})
        for hid, (pos, rel) in seen.items():
            hh = self.hidden[hid]
            diameter = float(src.diameter_m) / float(np.linalg.norm(lamp - pos))
            normals = self.beam_normals(hid)
            own = np.zeros(coarse.shape)
            for nn in normals:
                own += render_spot(pos, nn, lamp, diameter, hh.mirror, coarse, rng=rng,
                                   n_rays=RENDER_RAYS // len(normals)) / len(normals)
            img += self.spot_truth.place(own, coarse, grid.center + rel, shifts.get(hid))
        self.spot_truth.record({h: grid.center + rel + shifts.get(h, 0.0) for h, (_, rel) in seen.items()})
        if coarse.shape == grid.shape:
            return img
        # Pixel centres of both grids span the same plane area: resize maps them consistently.
        return cv2.resize(img.astype(np.float32), (cols, rows), interpolation=cv2.INTER_LINEAR).astype(float)


def load_config_data(path: str | Path) -> dict:
    """The raw YAML mapping of a config file (validated by :func:`controller.config.load_config`
    first), its field file's path (``field.file``) made absolute: the mapping goes to places that
    do not know the file's folder."""
    data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    if data.get("field"):
        data["field"]["file"] = str(field_path(data["field"]["file"], str(path)).absolute())
    return data


