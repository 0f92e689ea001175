"""The server's address space, built once at start (docs/plant-integration.md, "OPC UA"):
namespace ``urn:heliocal``, every node's id the string of its browse path below ``Objects``
(``ns=<urn:heliocal>;s=Heliocal/Heliostats/H01/State``), browse names the objects' ids.

::

    Heliocal/
      LastCommand   the last AllOff or Park: {"method", "target", "user", "state", "detail", "time_utc"}
      Field/        Site, HeliostatCount, PredictedDaytimeErrorMrad
      Heliostats/<id>/  State, LastMeasurementUtc, LastErrorMrad, PredictedDaytimeErrorMrad,
                        ModelVersion, ModelAgeDays, Model/<term>, Park()
      Targets/<id>/     CenterEnuM, CameraOk
      Lamps/<channel>/  Lit;  Lamps/AllOff()
      Night/        Name, State, Planned, Measured, Progress, PredictedDaytimeErrorMrad, Start(), Stop()
      Alarms/       ActiveCount, UnacknowledgedCount, List, Acknowledge(AlarmId, Comment),
                    Shelve(AlarmId, Minutes); the alarms' AlarmConditionType events
      Models/       the ModelChangedEventType events (Heliostat, Version)
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field

from asyncua import Node, Server, ua

from controller.config import PlantConfig
from controller.geometry.model.tracking import TERMS

NAMESPACE = "urn:heliocal"
ROOT = "Heliocal"

Method = Callable[..., Awaitable]


@dataclass
class Nodes:
    """The variables by path below ``Heliocal/`` (e.g. ``Night/State``) and the event sources."""

    idx: int
    variables: dict[str, Node] = field(default_factory=dict)
    alarms: Node | None = None
    models: Node | None = None
    model_changed: Node | None = None  # the ModelChangedEventType


def node_id(idx: int, path: str) -> ua.NodeId:
    return ua.NodeId(f"{ROOT}/{path}" if path else ROOT, idx)


async def _object(parent: Node, idx: int, path: str, name: str, folder: bool = False) -> Node:
    qn = ua.QualifiedName(name, idx)
    return await (parent.add_folder if folder else parent.add_object)(node_id(idx, path), qn)


async def _var(nodes: Nodes, parent: Node, path: str, name: str, value, vtype: ua.VariantType) -> Node:
    full = f"{path}/{name}"
    v = await parent.add_variable(node_id(nodes.idx, full), ua.QualifiedName(name, nodes.idx),
                                  ua.Variant(value, vtype))
    nodes.variables[full] = v
    return v


async def _method(parent: Node, idx: int, path: str, name: str, func: Method, inputs=()) -> Node:
    args = []
    for arg_name, vtype in inputs:
        a = ua.Argument()
        a.Name, a.DataType, a.ValueRank = arg_name, ua.NodeId(vtype.value), -1
        args.append(a)
    qn = ua.QualifiedName(name, idx)
    return await parent.add_method(node_id(idx, f"{path}/{name}"), qn, func, args, [])


async def build(server: Server, cfg: PlantConfig, ids: list[str], methods: dict[str, Method]) -> Nodes:
    """The address space of ``cfg``'s heliostats ``ids``; ``methods`` by name: ``park(hid)``
    (a factory), ``all_off``, ``start``, ``stop``, ``acknowledge``, ``shelve``."""
    D, S, U, B = ua.VariantType.Double, ua.VariantType.String, ua.VariantType.UInt32, ua.VariantType.Boolean
    idx = await server.register_namespace(NAMESPACE)
    nodes = Nodes(idx)
    nan = float("nan")
    root = await _object(server.nodes.objects, idx, "", ROOT, folder=True)
    lc = await root.add_variable(node_id(idx, "LastCommand"), ua.QualifiedName("LastCommand", idx),
                                 ua.Variant("{}", S))
    nodes.variables["LastCommand"] = lc
    f = await _object(root, idx, "Field", "Field")
    await _var(nodes, f, "Field", "Site", cfg.site.name, S)
    await _var(nodes, f, "Field", "HeliostatCount", len(ids), U)
    await _var(nodes, f, "Field", "PredictedDaytimeErrorMrad", nan, D)
    hs = await _object(root, idx, "Heliostats", "Heliostats", folder=True)
    for hid in ids:
        p = f"Heliostats/{hid}"
        h = await _object(hs, idx, p, hid)
        await _var(nodes, h, p, "State", "uncalibrated", S)
        await _var(nodes, h, p, "LastMeasurementUtc", "", S)
        await _var(nodes, h, p, "LastErrorMrad", nan, D)
        await _var(nodes, h, p, "PredictedDaytimeErrorMrad", nan, D)
        await _var(nodes, h, p, "ModelVersion", 0, U)
        await _var(nodes, h, p, "ModelAgeDays", nan, D)
        m = await _object(h, idx, f"{p}/Model", "Model")
        for t in TERMS:
            await _var(nodes, m, f"{p}/Model", t.key, 0.0, D)
        await _method(h, idx, p, "Park", methods["park"](hid))
    ts = await _object(root, idx, "Targets", "Targets", folder=True)
    for t in cfg.targets:
        p = f"Targets/{t.id}"
        tn = await _object(ts, idx, p, t.id)
        await _var(nodes, tn, p, "CenterEnuM", [float(c) for c in t.center_enu_m], D)
        await _var(nodes, tn, p, "CameraOk", True, B)
    lamps = await _object(root, idx, "Lamps", "Lamps", folder=True)
    for channel in (cfg.lamps.channels if cfg.lamps is not None else {}):
        p = f"Lamps/{channel}"
        await _var(nodes, await _object(lamps, idx, p, channel), p, "Lit", False, B)
    await _method(lamps, idx, "Lamps", "AllOff", methods["all_off"])
    n = await _object(root, idx, "Night", "Night")
    for name, value, vtype in (("Name", "", S), ("State", "idle", S), ("Planned", 0, U), ("Measured", 0, U),
                               ("Progress", 0.0, D), ("PredictedDaytimeErrorMrad", nan, D)):
        await _var(nodes, n, "Night", name, value, vtype)
    await _method(n, idx, "Night", "Start", methods["start"])
    await _method(n, idx, "Night", "Stop", methods["stop"])
    a = await _object(root, idx, "Alarms", "Alarms")
    await _var(nodes, a, "Alarms", "ActiveCount", 0, U)
    await _var(nodes, a, "Alarms", "UnacknowledgedCount", 0, U)
    await _var(nodes, a, "Alarms", "List", "[]", S)
    await _method(a, idx, "Alarms", "Acknowledge", methods["acknowledge"], (("AlarmId", U), ("Comment", S)))
    await _method(a, idx, "Alarms", "Shelve", methods["shelve"], (("AlarmId", U), ("Minutes", D)))
    nodes.alarms = a
    nodes.models = await _object(root, idx, "Models", "Models")
    nodes.model_changed = await server.create_custom_event_type(
        idx, "ModelChangedEventType", ua.ObjectIds.BaseEventType,
        [("Heliostat", ua.VariantType.String), ("Version", ua.VariantType.UInt32)])
    for node in (root, nodes.alarms, nodes.models):
        await node.set_event_notifier([ua.EventNotifier.SubscribeToEvents])
    return nodes
