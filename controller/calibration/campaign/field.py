"""What a campaign or a night runs on: one field, its devices, its records and its time.

As in Bluesky/ophyd, the devices are built once from the configuration — for a real plant by
the interface layer (``controller.commands.field``), for the simulated plant from the
devices ``simplant`` provides — and everything that runs (a campaign, a planned night,
commissioning, the console) is handed this one object. Nothing here knows whether the plant
is simulated.

* ``pool``: the link pool that opens each heliostat's drive (:class:`controller.devices.factory.LinkPool`);
* ``cameras``: the double-CCD camera looking at each target, by target id;
* ``lamps``: the field's lamps (:class:`Lamps`): a lamp panel with confirmation, or the
  operator when no panel is configured;
* ``store`` / ``images``: the record store and the frame archive (handed in by the interface layer);
* ``time``: plant time (:class:`controller.devices.plant_time.PlantTime`);
* ``library``: the error library the beam chain matches against (None: no recognition);
* ``alarms`` / ``audit``: the plant's alarm list and audit trail (handed in by the interface
  layer, :mod:`controller.alarms.sink`): a lamp that does not confirm raises its alarm, every
  lamp switched and every model changed is recorded.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from controller.alarms.conditions import LAMP_NOT_DARK, LAMP_NOT_LIT
from controller.alarms.lamps import lamp_alarms
from controller.alarms.sink import NO_ALARMS, NO_AUDIT, AlarmSink, AuditSink
from controller.calibration.records import ModelRecord
from controller.config import PlantConfig
from controller.devices.drive import Drive, DriveLimits
from controller.devices.lamp_drivers import open_lamp_panel
from controller.devices.lamp_panel import LampPanel, LampState, light_only, lights_out
from controller.devices.plant_time import WALL, PlantTime
from controller.errors import DeviceError


@dataclass(frozen=True)
class LampLit:
    """A lamp lit for measuring: its id, whether its state was confirmed by the plant (a lamp
    panel's confirmation input) or only asked of the operator, and the plant UTC it was lit at."""

    lamp: str
    confirmed: bool
    by: str  # "panel" | "operator"
    utc: str

    def to_json(self) -> dict:
        return {"lamp": self.lamp, "confirmed": self.confirmed, "by": self.by, "utc": self.utc}


@dataclass(frozen=True)
class LampEnd:
    """One lamp channel as a night or campaign left it (the ``lamp_states`` table): ``state``
    ``dark`` (confirmed dark by the panel), ``lit`` (still confirmed lit after it was switched
    off), ``no_answer`` (the panel could not tell) or ``operator`` (no panel: the operator was
    asked to switch it off); ``commanded``: what the panel was last told (None: unknown);
    ``detail``: why it is not dark."""

    channel: str
    state: str
    commanded: bool | None = None
    detail: str | None = None

    @property
    def dark(self) -> bool:
        return self.state == "dark"

    def to_json(self) -> dict:
        return {"channel": self.channel, "state": self.state, "commanded": self.commanded,
                "detail": self.detail}


class Lamps(Protocol):
    """The field's lamps. ``light_only`` switches every other lamp off and ``lamp`` on and
    returns once the plant confirms it (or raises naming the lamp); ``lights_out`` switches
    every lamp off (confirmed dark); ``states`` reads every channel (``channels``) as it is now.
    The targets' fiducial lamps are the camera registration's
    (:func:`controller.devices.lamp_drivers.fiducial_switch`)."""

    channels: tuple[str, ...]
    timeout_s: float

    def light_only(self, lamp: str) -> LampLit: ...
    def lights_out(self) -> None: ...
    def states(self) -> list[LampState]: ...


@dataclass
class Field:
    """One field's devices, records and time (module docstring). ``config_path`` and
    ``config_sha256`` name the configuration campaigns are started with (a resume with another
    one is refused); ``meta`` goes into every campaign's record (e.g. ``plant: simulated``)."""

    cfg: PlantConfig
    config_path: str
    config_sha256: str
    store: Any  # controller.calibration.campaign.runner.RecordStore
    pool: Any  # controller.devices.factory.LinkPool
    cameras: dict[str, Any]
    time: PlantTime = WALL
    lamps: Lamps | None = None
    images: Any = None  # controller.calibration.campaign.runner.ImageSink
    library: Any = None
    meta: dict = field(default_factory=dict)
    label: str = "field"
    alarms: AlarmSink = NO_ALARMS
    audit: AuditSink = NO_AUDIT
    _drives: dict[str, Drive] = field(default_factory=dict, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def drive(self, hid: str) -> Drive:
        """The drive of ``hid`` with its configured soft limits, opened once. Drives on one bus
        may be used from several threads: each link holds its lock per transaction."""
        with self._lock:
            if hid not in self._drives:
                h = self.cfg.heliostat(hid)
                self._drives[hid] = self.pool.drive(h.link, DriveLimits.from_axes(h.axes))
            return self._drives[hid]

    def camera(self, target: str | None = None) -> Any:
        """The camera looking at ``target`` (default: the calibration target); DeviceError naming
        the target when the field has none there (e.g. recorded pairs of one target only)."""
        tid = target or self.cfg.calibration.target
        if tid not in self.cameras:
            have = ", ".join(self.cameras) or "none"
            raise DeviceError(f"no camera looks at target {tid!r} (cameras at: {have})")
        return self.cameras[tid]

    def model(self, hid: str) -> ModelRecord | None:
        """The latest fitted tracking model of ``hid`` (None before its first)."""
        return self.store.latest_model(hid)

    def models(self, ids: list[str]) -> dict[str, ModelRecord | None]:
        """The latest model of each of ``ids`` (None before its first), in one query."""
        got = self.store.latest_models(ids)
        return {hid: got.get(hid) for hid in ids}

    def with_models(self, ids: list[str]) -> set[str]:
        """Those of ``ids`` that have a fitted model."""
        return self.store.with_models(ids)

    def light(self, lamp: str, ask_operator: Callable[[str], None]) -> LampLit:
        """Light ``lamp`` for measuring: through the lamp panel (every other lamp off, the lamp
        confirmed lit, else LampError naming it) or, without one, by asking the operator
        (``ask_operator(lamp)``, a campaign observer's ``light_source_needed``)."""
        if self.lamps is not None:
            with lamp_alarms(self.alarms):
                lit = self.lamps.light_only(lamp)
            self.alarms.clear_alarm(LAMP_NOT_LIT, lamp)
            self.audit.record("lamp.on", lamp, "every other lamp confirmed dark, this one lit")
            return lit
        ask_operator(lamp)
        return LampLit(lamp, False, "operator", self.time.utc())

    def lights_out(self, ask_operator: Callable[[], None] | None = None) -> None:
        """Every lamp off (confirmed by the panel: a lamp that is not raises its alarm), or the
        operator asked to switch them off."""
        if self.lamps is not None:
            with lamp_alarms(self.alarms):
                self.lamps.lights_out()
            self.alarms.clear_alarm(LAMP_NOT_DARK)
            self.audit.record("lamps.off", "all", "every lamp confirmed dark")
        elif ask_operator is not None:
            ask_operator()


class PanelLamps:
    """A lamp panel (:mod:`controller.devices.lamp_panel`) as a field's :class:`Lamps`: every
    switch waits for the panel's confirmation input, up to ``timeout_s`` plant seconds
    (``lamps.confirm_timeout_s``); LampNotConfirmed names the lamp otherwise."""

    def __init__(self, panel: LampPanel, time: PlantTime, timeout_s: float) -> None:
        self.panel = panel
        self.time = time
        self.timeout_s = timeout_s

    @classmethod
    def open(cls, cfg, time: PlantTime) -> PanelLamps:
        """The panel of the configuration's ``lamps:`` section."""
        return cls(open_lamp_panel(cfg), time, cfg.confirm_timeout_s)

    def light_only(self, lamp: str) -> LampLit:
        light_only(self.panel, lamp, time=self.time, timeout_s=self.timeout_s)
        return LampLit(lamp, True, "panel", self.time.utc())

    def lights_out(self) -> None:
        lights_out(self.panel, time=self.time, timeout_s=self.timeout_s)

    @property
    def channels(self) -> tuple[str, ...]:
        return self.panel.channels

    def states(self) -> list[LampState]:
        return self.panel.states()

    def close(self) -> None:
        self.panel.close()
