"""A rehearsal field: the simulated plant of a configuration as one process whose every device
is on a real transport, and the configuration that points the product at it
(``heliocal sim plant``, docs/getting-started.md).

* the drives as the configuration's links say: the serial firmware on ptys, the Modbus
  heliostats behind a Modbus TCP server on 127.0.0.1 (or RTU on a pty)
  (:mod:`simplant.devices.plant_drives`);
* the lamp panel on Modbus TCP, 127.0.0.1 (:mod:`simplant.devices.lamp_panel`);
* each target's double-CCD camera as two GigE Vision imagers (:mod:`simplant.devices.gige_plant`),
  rendering what the plant's heliostats do.

:meth:`RehearsalPlant.start` serves them, waits until every device answers through the
product's own drivers and then writes the configuration ``out``: the one given, its field as it
gives it (heliostats inline, or its field file), with the devices' addresses — links, a
``lamps:`` section, ``camera.driver: gige`` for every target's camera, the cameras' response
files — and relative paths made absolute. :meth:`RehearsalPlant.stop` stops serving and removes
what it created: that file and the folder of ptys and response files.
"""

from __future__ import annotations

import copy
import os
import shutil
import tempfile
import time
from pathlib import Path

import yaml

from controller.config import PlantConfig, parse_config
from controller.devices.drive import DriveLimits
from controller.devices.factory import LinkPool
from controller.devices.lamp_drivers import open_lamp_panel
from controller.errors import DeviceError, InputError
from simplant.devices.gige_imager import aravis, discover
from simplant.devices.gige_plant import GigeCamera
from simplant.plant import SimulatedPlant, load_config_data
from simplant.settings import SimulationSettings

MAX_SENSOR_PX = 2048  # the fake GigE imager's sensor (its SensorWidth, SensorHeight)
# The simulated cameras render in software: give the controller's frame wait room for it.
FRAME_TIMEOUT_MS = 60_000
ANSWER_S = 10.0  # how long every device has to answer before the plant gives up


class RehearsalPlant:
    """The rehearsal field of configuration file ``config`` (validated as ``cfg``), its
    configuration to be written to ``out``."""

    def __init__(self, config: str | Path, cfg: PlantConfig, out: Path, settings: SimulationSettings) -> None:
        for t in cfg.targets:
            cam = cfg.camera_of(t.id)
            if cam.bit_depth not in (8, 16) or max(cam.width_px, cam.height_px) > MAX_SENSOR_PX:
                raise InputError(f"{config}: the camera of target {t.id!r}: the simulated GigE imagers "
                                 f"deliver Mono8 or Mono16 frames of at most {MAX_SENSOR_PX}x{MAX_SENSOR_PX} "
                                 f"pixels (bit_depth {cam.bit_depth}, {cam.width_px}x{cam.height_px})")
        aravis()  # before anything is served
        self.config = Path(config)
        self.out = out
        self.run_dir = Path(tempfile.mkdtemp(prefix="heliocal-plant-"))
        try:
            self.plant = SimulatedPlant(load_config_data(config), self.run_dir, settings=settings,
                                        source=str(config))
        except BaseException:
            shutil.rmtree(self.run_dir, ignore_errors=True)
            raise
        self.cameras: dict[str, GigeCamera] = {}
        self.written = False

    def start(self) -> dict:
        """Serve every device, wait until each answers, write ``out``; what serves where."""
        try:
            cfg = self.plant.start()
        except ValueError as exc:  # a field the simulated plant cannot serve (simplant.devices.plant_drives)
            raise InputError(f"{self.config}: {exc}") from None
        data = self.plant.data
        shared = None  # the top-level camera section goes to the first target without its own
        for k, t in enumerate(cfg.targets):
            self.cameras[t.id] = GigeCamera(self.plant.cameras[t.id], f"HC{os.getpid() % 10000}-{k + 1}")
            low, high = self.cameras[t.id].start()
            raw = data["targets"][k]
            if raw.get("camera") is None:
                if shared is None:
                    shared = raw["camera"] = data["camera"]
                else:  # one camera cannot look at two targets: this one gets its own
                    raw["camera"] = copy.deepcopy(shared)
            raw["camera"]["driver"] = "gige"
            raw["camera"]["gige"] = {"low": low, "high": high, "trigger": "software",
                                     "timeout_ms": FRAME_TIMEOUT_MS}
        if shared is not None:
            for t in data["targets"]:
                if t.get("camera") is shared:
                    del t["camera"]  # it is the top-level one
        _absolute_paths(data, self.config)
        final = parse_config(data, str(self.out))
        self._wait_for_answers(final)
        tmp = self.out.with_name(f".{self.out.name}.tmp")
        tmp.write_text(f"# The rehearsal field of {self.config.absolute()}, served by heliocal sim plant "
                       f"(pid {os.getpid()}); removed when it stops.\n"
                       + yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
        os.replace(tmp, self.out)
        self.written = True
        return {"ok": True, "config": str(self.out), "heliostats": len(final.heliostats),
                "drives": sorted({" ".join(map(str, h.link.bus_key)) for h in final.heliostats}),
                "lamp_panel": f"{final.lamps.host}:{final.lamps.port}",
                "cameras": {t.id: [final.camera_of(t.id).gige.low, final.camera_of(t.id).gige.high]
                            for t in final.targets}}

    def _wait_for_answers(self, cfg: PlantConfig) -> None:
        """Until every drive, the lamp panel and every imager answers through the product's
        drivers (DeviceError naming the first that does not within :data:`ANSWER_S`)."""
        with LinkPool(timeout_s=0.5, retries=2) as pool:
            for h in cfg.heliostats:
                drive = pool.drive(h.link, DriveLimits.from_axes(h.axes))
                _until(f"the drive of {h.id}", lambda d=drive: d.status() is not None)
        with open_lamp_panel(cfg.lamps) as panel:
            _until("the lamp panel", lambda: len(panel.states()) == len(cfg.lamps.channels))
        for cam in self.cameras.values():
            for imager in cam.imagers:
                _until(f"the GigE imager {imager.address}", lambda a=imager.address: discover(a))

    def stop(self) -> None:
        """Stop serving; remove the written configuration and the run folder (idempotent)."""
        for cam in self.cameras.values():
            cam.stop()
        self.cameras.clear()
        self.plant.stop()
        if self.written:
            self.out.unlink(missing_ok=True)
            self.written = False
        shutil.rmtree(self.run_dir, ignore_errors=True)


def _until(what: str, answers) -> None:
    """Poll ``answers()`` until true; DeviceError after :data:`ANSWER_S`."""
    deadline = time.monotonic() + ANSWER_S
    while True:
        try:
            if answers():
                return
        except DeviceError:
            pass
        if time.monotonic() > deadline:
            raise DeviceError(f"the simulated plant: {what} does not answer")
        time.sleep(0.05)


def _absolute_paths(data: dict, config: Path) -> None:
    """Make the configuration's relative file paths absolute (``out`` may be anywhere): the error
    library and every camera's response file (the field file is already, :class:`SimulatedPlant`)."""
    base = config.resolve().parent

    def fix(section: dict, key: str) -> None:
        if section.get(key) and not Path(section[key]).is_absolute():
            section[key] = str(base / section[key])

    fix(data["calibration"], "library")
    for cam in [data["camera"], *(t["camera"] for t in data["targets"] if t.get("camera"))]:
        fix(cam, "crf_file")
