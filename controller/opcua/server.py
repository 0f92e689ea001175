"""The OPC UA server of ``heliocal opcua`` (asyncua): security, identities, the methods with
their roles, and the loop that keeps the address space and its events up to date from the
record store (docs/plant-integration.md, "OPC UA").

* Security: the endpoint offers Basic256Sha256 with Sign and with SignAndEncrypt (and, unless
  ``require_encryption``, no security — the password is still encrypted with the server's
  certificate). The server's key and self-signed certificate are made once in ``pki_dir``.
* Identities: username/password of the ``users`` accounts (:mod:`controller.opcua.access`);
  anonymous sessions are refused.
* Methods: ``Lamps/AllOff``, ``Heliostats/<id>/Park``, ``Night/Start``, ``Night/Stop``,
  ``Alarms/Acknowledge`` and ``Alarms/Shelve`` need the operator role; a viewer gets
  ``BadUserAccessDenied``. Every call, done or refused, is audited with the account's name.
  ``AllOff`` and ``Park`` wait for the plant (a lamp's confirmation, a move): they answer
  ``Good`` once accepted and go on in the background, one at a time (another meanwhile:
  ``BadInvalidState``), their outcome in ``LastCommand`` and, when a lamp does not confirm,
  its alarm — asyncua serves a connection's requests one after another, and a call that held
  the connection for seconds would starve the caller's publish and keep-alive requests.
* Values are written only when they change, every ``poll_s`` seconds; each new alarm event of
  the store is an ``AlarmConditionType`` event of ``Alarms``, each new model a
  ``ModelChangedEventType`` event of ``Models``.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import math
import socket
import sys
from pathlib import Path

from asyncua import Server, ua
from asyncua.crypto.cert_gen import setup_self_signed_certificate
from cryptography.x509.oid import ExtendedKeyUsageOID

from controller.alarms.states import parse_duration
from controller.config import PlantConfig
from controller.devices.lamp_panel import LampError
from controller.errors import HeliocalError, InputError
from controller.io.json_files import dumps_json
from controller.opcua.access import AccountUsers, Callers, caller
from controller.opcua.address_space import Nodes, build
from controller.opcua.plant import OpcPlant
from controller.opcua.snapshot import Snapshot, snapshot
from controller.storage.alarms import AlarmBook
from controller.storage.audit import AuditTrail
from controller.storage.db import CampaignStore
from controller.storage.users import Accounts, allows

APP_URI = "urn:heliocal:opcua-server"
log = logging.getLogger("heliocal.opcua")


def _say(text: str) -> None:
    print(f"heliocal opcua: {text}", file=sys.stderr, flush=True)


class HeliocalServer:
    """The server over ``store`` for the heliostats ``ids`` of ``cfg`` (module docstring)."""

    def __init__(self, cfg: PlantConfig, config_path: str, store: CampaignStore, ids: list[str], *,
                 endpoint: str, pki_dir: Path, poll_s: float = 1.0, require_encryption: bool = False) -> None:
        self.cfg, self.store, self.ids = cfg, store, ids
        self.endpoint, self.pki_dir, self.poll_s = endpoint, pki_dir, poll_s
        self.require_encryption = require_encryption
        self.plant = OpcPlant(cfg, config_path, store)
        self.alarms = AlarmBook(store)
        self.server: Server | None = None
        self.nodes: Nodes | None = None
        self._written: dict[str, object] = {}
        self._event_id = 0
        self._models: dict[str, int] | None = None
        self._lamp_panel = None
        self._command: asyncio.Task | None = None
        self._last: dict = {}

    # -- set-up -------------------------------------------------------------------------------
    async def start(self) -> None:
        logging.getLogger("asyncua").setLevel(logging.ERROR)
        server = Server(user_manager=AccountUsers(Accounts(self.store)))
        await server.init()
        server.set_endpoint(self.endpoint)
        server.set_server_name("heliocal")
        await server.set_application_uri(APP_URI)
        self.pki_dir.mkdir(parents=True, exist_ok=True)
        key, cert = self.pki_dir / "server-key.pem", self.pki_dir / "server-cert.der"
        uses = [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
        subject = {"commonName": "heliocal OPC UA server", "organizationName": "heliocal"}
        await setup_self_signed_certificate(key, cert, APP_URI, socket.gethostname(), uses, subject)
        await server.load_certificate(str(cert))
        await server.load_private_key(str(key))
        policies = [ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt]
        if not self.require_encryption:
            policies += [ua.SecurityPolicyType.Basic256Sha256_Sign, ua.SecurityPolicyType.NoSecurity]
        server.set_security_policy(policies, permission_ruleset=Callers())
        server.set_identity_tokens([ua.UserNameIdentityToken])
        self.nodes = await build(server, self.cfg, self.ids, {
            "park": lambda hid: self._method("operator", "Park", hid, functools.partial(self._park, hid),
                                             background=True),
            "all_off": self._method("operator", "AllOff", "lamps", self.plant.all_off, background=True),
            "start": self._method("operator", "Start", "night", self.plant.start_night),
            "stop": self._method("operator", "Stop", "night", self.plant.stop_night),
            "acknowledge": self._method("operator", "Acknowledge", "alarm", self._acknowledge, invalid=True),
            "shelve": self._method("operator", "Shelve", "alarm", self._shelve, invalid=True)})
        self._event_id = await asyncio.to_thread(self.alarms.last_event_id)
        self.server = server
        await server.start()

    async def stop(self) -> None:
        if self.server is not None:
            await self.server.stop()
        if self._command is not None:
            await asyncio.wait([self._command])
        await asyncio.to_thread(self.plant.close)
        if self._lamp_panel is not None:
            self._lamp_panel.close()

    # -- methods ------------------------------------------------------------------------------
    def _method(self, needed: str, name: str, target: str, action, *, invalid: bool = False,
                background: bool = False):
        """An asyncua method: the caller's role checked (refusals audited), ``action(user, *args)``
        run in a worker thread (``background``: accepted at once, module docstring); heliocal's
        errors become status codes."""
        async def call(parent, *args):
            user = caller()
            if user is None:
                return ua.StatusCode(ua.StatusCodes.BadUserAccessDenied)
            if not allows(user.heliocal_role, needed):
                why = f"{user.heliocal_role} may not call {name}: it needs the {needed} role"
                trail = AuditTrail(self.store, user.name)
                await asyncio.to_thread(trail.record, "denied", f"{name} {target}", why)
                _say(f"{user.name} ({user.heliocal_role}) refused {name} {target}")
                return ua.StatusCode(ua.StatusCodes.BadUserAccessDenied)
            values = [a.Value if isinstance(a, ua.Variant) else a for a in args]
            if background:
                if self._command is not None and not self._command.done():
                    _say(f"{user.name} {name} {target}: refused, {self._last['method']} still running")
                    return ua.StatusCode(ua.StatusCodes.BadInvalidState)
                if name == "AllOff" and self.cfg.lamps is None:
                    return ua.StatusCode(ua.StatusCodes.BadNotSupported)
                await self._set_last(name, target, user.name, "running", "")
                self._command = asyncio.create_task(self._background(name, target, user.name, action, values))
                return []
            try:
                await asyncio.to_thread(action, user.name, *values)
            except LampError as exc:
                _say(f"{user.name} {name} {target}: {exc}")
                return ua.StatusCode(ua.StatusCodes.BadDeviceFailure)
            except InputError as exc:
                _say(f"{user.name} {name} {target}: {exc}")
                code = ua.StatusCodes.BadInvalidArgument if invalid else ua.StatusCodes.BadInvalidState
                if "already acknowledged" in str(exc):
                    code = ua.StatusCodes.BadConditionBranchAlreadyAcked
                return ua.StatusCode(code)
            except HeliocalError as exc:
                _say(f"{user.name} {name} {target}: {exc}")
                return ua.StatusCode(ua.StatusCodes.BadDeviceFailure)
            _say(f"{user.name} {name} {target}: done")
            await self.refresh()
            return []
        return call

    async def _background(self, name: str, target: str, user: str, action, values) -> None:
        try:
            await asyncio.to_thread(action, user, *values)
        except HeliocalError as exc:
            _say(f"{user} {name} {target}: {exc}")
            await self._set_last(name, target, user, "failed", str(exc))
        else:
            _say(f"{user} {name} {target}: done")
            await self._set_last(name, target, user, "done", "")
        await self.refresh()

    async def _set_last(self, name: str, target: str, user: str, state: str, detail: str) -> None:
        from controller.alarms.states import now_utc

        self._last = {"method": name, "target": target, "user": user, "state": state, "detail": detail,
                      "time_utc": now_utc().isoformat(timespec="milliseconds")}
        await self._write("LastCommand", dumps_json(self._last), ua.VariantType.String)

    def _park(self, hid: str, user: str) -> None:
        self.plant.park(hid, user)

    def _acknowledge(self, user: str, alarm_id: int, comment: str = "") -> None:
        self.alarms.acknowledge(int(alarm_id), user, comment or "")

    def _shelve(self, user: str, alarm_id: int, minutes: float) -> None:
        if not (isinstance(minutes, (int, float)) and math.isfinite(minutes)):
            raise InputError(f"Minutes: {minutes!r} is not a number")
        self.alarms.shelve(int(alarm_id), user, parse_duration(f"{float(minutes)}m", "Minutes"))

    # -- values and events ----------------------------------------------------------------------
    async def run(self, stop: asyncio.Event) -> None:
        """Refresh every ``poll_s`` until ``stop`` is set."""
        while not stop.is_set():
            await self.refresh()
            try:
                await asyncio.wait_for(stop.wait(), self.poll_s)
            except TimeoutError:
                pass

    async def refresh(self) -> None:
        snap = await asyncio.to_thread(snapshot, self.store, self.ids)
        await self._values(snap)
        await self._alarm_events()
        await self._model_events(snap)
        if self.cfg.lamps is not None and self.cfg.lamps.driver == "modbus-tcp":
            await self._lamps()

    async def _write(self, path: str, value, vtype: ua.VariantType) -> None:
        old = self._written.get(path)
        same = old == value or (isinstance(value, float) and isinstance(old, float)
                                and math.isnan(value) and math.isnan(old))
        if not same:
            await self.nodes.variables[path].write_value(ua.Variant(value, vtype))
            self._written[path] = value

    async def _values(self, s: Snapshot) -> None:
        V = ua.VariantType
        D, S, U, B = V.Double, V.String, V.UInt32, V.Boolean
        n = s.night
        for name, value, vtype in (("Name", n.name, S), ("State", n.state, S), ("Planned", n.planned, U),
                                   ("Measured", n.measured, U), ("Progress", n.progress, D),
                                   ("PredictedDaytimeErrorMrad", n.predicted_mrad, D)):
            await self._write(f"Night/{name}", value, vtype)
        await self._write("Field/PredictedDaytimeErrorMrad", n.predicted_mrad, D)
        cycles = self.plant.cycle_states()
        for hid, h in s.heliostats.items():
            p = f"Heliostats/{hid}"
            await self._write(f"{p}/State", cycles.get(hid, h.state), S)
            await self._write(f"{p}/LastMeasurementUtc", h.last_measurement_utc or "", S)
            await self._write(f"{p}/LastErrorMrad", h.last_error_mrad, D)
            await self._write(f"{p}/PredictedDaytimeErrorMrad", h.predicted_mrad, D)
            await self._write(f"{p}/ModelVersion", h.model_version, U)
            await self._write(f"{p}/ModelAgeDays", h.model_age_days, D)
            for key, value in h.terms.items():
                if f"{p}/Model/{key}" in self.nodes.variables:
                    await self._write(f"{p}/Model/{key}", value, D)
        active = [a for a in s.alarms if a["active"]]
        await self._write("Alarms/ActiveCount", len(active), U)
        await self._write("Alarms/UnacknowledgedCount", sum(not a["acknowledged"] for a in s.alarms), U)
        await self._write("Alarms/List", dumps_json(s.alarms), S)
        gone = {a["source"] for a in active if a["condition"] == "camera_gone"}
        for t in self.cfg.targets:
            await self._write(f"Targets/{t.id}/CameraOk", t.id not in gone, B)

    async def _alarm_events(self) -> None:
        events = await asyncio.to_thread(self.alarms.events, self._event_id)
        for e in events:
            alarm = await asyncio.to_thread(self.alarms.alarm, e["alarm_id"])
            gen = await self.server.get_event_generator(ua.ObjectIds.AlarmConditionType, self.nodes.alarms)
            ev = gen.event
            ev.SourceName = alarm.source
            ev.ConditionName = alarm.condition
            ev.Message = ua.LocalizedText(f"{e['kind']}: {alarm.message}")
            ev.Severity = alarm.severity
            ev.ActiveState = ua.LocalizedText("Active" if alarm.active else "Inactive")
            setattr(ev, "ActiveState/Id", alarm.active)
            ev.AckedState = ua.LocalizedText("Acknowledged" if alarm.acked else "Unacknowledged")
            setattr(ev, "AckedState/Id", alarm.acked)
            ev.Retain = alarm.active or not alarm.acked
            ev.ClientUserId = e["user"] or ""
            ev.Comment = ua.LocalizedText(alarm.ack_comment or "")
            await gen.trigger(message=f"{e['kind']}: {alarm.message}")
            self._event_id = e["id"]

    async def _model_events(self, s: Snapshot) -> None:
        if self._models is not None:
            for hid, model_id in s.model_ids.items():
                if hid in s.heliostats and self._models.get(hid) != model_id:
                    gen = await self.server.get_event_generator(self.nodes.model_changed, self.nodes.models)
                    version = s.heliostats[hid].model_version
                    gen.event.Heliostat, gen.event.Version = hid, version
                    gen.event.Severity = 100
                    gen.event.SourceName = hid
                    await gen.trigger(message=f"model of {hid} changed: version {version}")
        self._models = dict(s.model_ids)

    async def _lamps(self) -> None:
        from controller.devices.lamp_drivers import open_lamp_panel

        try:
            if self._lamp_panel is None:
                self._lamp_panel = open_lamp_panel(self.cfg.lamps)
            states = await asyncio.to_thread(self._lamp_panel.states)
        except HeliocalError:
            if self._lamp_panel is not None:
                self._lamp_panel.close()
            self._lamp_panel = None
            return
        for st in states:
            if f"Lamps/{st.channel}/Lit" in self.nodes.variables:
                await self._write(f"Lamps/{st.channel}/Lit", bool(st.lit), ua.VariantType.Boolean)
