"""What the OPC UA server's methods drive: the lamp panel (all lamps off), a heliostat's drive
(park along the beam-safe path) and a planned night on the configured field — each with the
database's campaign lock, as the console and the CLI take it, so nothing drives twice.

Opened on first use and closed at shutdown: a server that only publishes holds no drive, bus
or camera. Every action records who asked in the audit trail (the field's lamps, the night's
start and end through :class:`controller.calibration.campaign.field.Field`, a park here).
"""

from __future__ import annotations

import threading
from contextlib import ExitStack
from pathlib import Path

from controller.calibration.campaign.field import Field, PanelLamps
from controller.calibration.campaign.observers import CampaignObserver
from controller.calibration.cycle.commissioning import Commissioning
from controller.calibration.night.planned import PlannedNight, tonight
from controller.config import PlantConfig
from controller.devices.drive import DriveLimits
from controller.devices.factory import LinkPool
from controller.devices.plant_time import WALL
from controller.errors import HeliocalError, InputError
from controller.storage.alarms import AlarmBook
from controller.storage.audit import AuditTrail
from controller.storage.db import CampaignStore
from controller.storage.nights import NightBook


class _States(CampaignObserver):
    """The cycle state of each heliostat while this server's night runs."""

    def __init__(self) -> None:
        self.states: dict[str, str] = {}

    def state_changed(self, heliostat_id: str, state: str) -> None:
        self.states[heliostat_id] = state


class OpcPlant:
    """The field of ``cfg`` (``config_path``) behind the server's methods, on ``store``."""

    def __init__(self, cfg: PlantConfig, config_path: str | Path, store: CampaignStore) -> None:
        self.cfg = cfg
        self.config_path = str(config_path)
        self.store = store
        self.alarms = AlarmBook(store)
        self._stack = ExitStack()
        self._pool: LinkPool | None = None
        self._field: Field | None = None
        self._busy = threading.Lock()
        self._night: PlannedNight | None = None
        self._thread: threading.Thread | None = None
        self._states = _States()

    def _audit(self, user: str) -> AuditTrail:
        return AuditTrail(self.store, user)

    # -- lamps -----------------------------------------------------------------------------------
    def all_off(self, user: str) -> None:
        """Every lamp off and confirmed dark (a lamp that is not raises its alarm), audited."""
        if self.cfg.lamps is None:
            raise InputError("the configuration has no lamps: section (no lamp panel to switch)")
        lamps = PanelLamps.open(self.cfg.lamps, WALL)
        try:
            lamp_field = Field(self.cfg, self.config_path, "", self.store, None, {}, WALL, lamps,
                               alarms=self.alarms, audit=self._audit(user))
            lamp_field.lights_out()
        finally:
            lamps.close()

    # -- heliostats ------------------------------------------------------------------------------
    def park(self, hid: str, user: str) -> dict:
        """Park ``hid`` at its standby along the beam-safe path, audited."""
        self.cfg.heliostat(hid)
        with self._busy:
            if self.running:
                raise InputError(f"{hid}: the night drives the heliostats now; stop it first")
            self.store.campaign_lock.acquire("opcua")
            try:
                h = self.cfg.heliostat(hid)
                drive = self._drives().drive(h.link, DriveLimits.from_axes(h.axes))
                session = Commissioning(self.cfg, hid, drive, None, model=self.store.latest_model(hid))
                out = session.park()
            finally:
                self.store.campaign_lock.release()
        self._audit(user).record("heliostat.park", hid,
                                 f"parked at az {out.get('az_steps')} el {out.get('el_steps')} steps")
        return out

    def _drives(self) -> LinkPool:
        if self._pool is None:
            self._pool = self._stack.enter_context(LinkPool())
        return self._pool

    # -- the night -------------------------------------------------------------------------------
    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start_night(self, user: str) -> str:
        """Start (or resume) tonight's planned night on the configured field; its name."""
        with self._busy:
            if self.running:
                raise InputError(f"night {self._night.name} is running")
            self.store.campaign_lock.acquire("opcua night")
            try:
                field = self._open_field()
            except BaseException:
                self.store.campaign_lock.release()
                raise
            field.audit = self._audit(user)
            book = NightBook(self.store)
            name, index = tonight(book, book.base_name() or self.cfg.site.name)
            self._states.states.clear()
            self._night = PlannedNight(field, book, name, index, observers=[self._states])
            self._thread = threading.Thread(target=self._run, args=(self._night,), name="opcua-night",
                                            daemon=True)
            self._thread.start()
        return name

    def _run(self, night: PlannedNight) -> None:
        try:
            night.run()
        except HeliocalError:
            pass  # the night recorded how it ended; the address space reads it from the store
        finally:
            self.store.campaign_lock.release()

    def stop_night(self, user: str) -> str:
        if not self.running or self._night is None:
            raise InputError("no night is running")
        self._night.request_stop()
        self._audit(user).record("night.stop", self._night.name, "asked over OPC UA")
        return self._night.name

    def cycle_states(self) -> dict[str, str]:
        return dict(self._states.states) if self.running else {}

    def _open_field(self) -> Field:
        if self._field is None:
            from controller.commands.field import real_field

            fs = self._stack.enter_context(real_field(self.cfg, self.config_path, self.store))
            self._field = fs.field
        return self._field

    def close(self, timeout_s: float = 60.0) -> None:
        """Stop a running night (beams parked) and release every device."""
        if self.running and self._night is not None:
            self._night.request_stop()
            self._thread.join(timeout_s)
        self._stack.close()

