"""The layer contract of docs/architecture.md, checked on every import of the product.

Layers from the wire up: wire (``firmware_proto``) → drivers (``controller.devices``) → pure
domain (``geometry``, ``imaging``, ``flux``, ``recognition``) → orchestration
(``calibration``) → interfaces (``commands``, ``reports``, ``storage``, ``console``, ``cli``).
Every import — at module level or inside a function — must point to the importer's own layer
or one allowed below it. The simulated plant (``simplant``) sits outside: the product never
imports it, except the commands that run the simulator.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PRODUCT = ("controller", "firmware_proto")

# Imported by every layer: the error types and the validated plant configuration (data only).
FOUNDATION = {"controller", "controller.errors", "controller.config", "controller.axis_config",
              "controller.camera_config", "controller.link_config", "controller.lamp_config",
              "controller.config_rules", "controller.heliostat_config", "controller.field_file",
              "controller.alarm_config"}

LAYERS: dict[str, set[str]] = {
    "wire": {"firmware_proto"},
    "io": {"controller.io"},
    "devices": {"controller.devices"},
    "domain": {"controller.geometry", "controller.imaging", "controller.flux", "controller.recognition"},
    "domain-io": set(),  # modules named *_io inside a domain package: their file handling
    "orchestration": {"controller.calibration", "controller.alarms"},
    "interfaces": {"controller.commands", "controller.reports", "controller.storage", "controller.console",
                   "controller.opcua", "controller.hfcs", "controller.cli"},
}

# Which layers each layer may import (besides FOUNDATION and itself).
ALLOWED: dict[str, set[str]] = {
    "foundation": {"io"},  # the configuration loader reads its YAML through controller.io
    "wire": set(),
    "io": set(),
    "devices": {"wire", "io"},
    "domain": set(),
    "domain-io": {"domain", "io"},
    "orchestration": {"wire", "devices", "domain", "domain-io", "io"},
    "interfaces": {"wire", "devices", "domain", "domain-io", "io", "orchestration"},
}

# A domain module may reach its own file handling only through a documented compatibility
# entry point, imported lazily inside that function (a public contract older than the split).
COMPAT_LAZY = {("controller.imaging.crf", "controller.imaging.crf_io")}

# The commands that run the simulated plant (they import it lazily, in their --simulate path).
SIMULATOR_USERS = ("controller.commands.demo", "controller.commands._demo_coarse",
                   "controller.commands._field", "controller.commands._simulate",
                   "controller.commands._night",
                   "controller.commands.campaign", "controller.commands.commission",
                   "controller.commands.sim", "controller.commands.report.weighting",
                   "controller.commands.console")

# The product's orchestration the simulated plant must never import: it provides devices and
# truth (like ophyd.sim), it does not assemble campaigns, nights or lamp changes itself.
ORCHESTRATION_OPERATIONS = ("controller.calibration.campaign.runner",
                            "controller.calibration.night.passes",
                            "controller.calibration.night.planned",
                            "controller.calibration.night.lamp_change",
                            "controller.calibration.night.planner",
                            "controller.calibration.campaign.parallel",
                            "controller.calibration.cycle.machine")

# Modules allowed over MAX_LINES, with the reason (one cohesive thing each).
MAX_LINES = 400
LONG_MODULES: dict[str, str] = {}


def layer_of(module: str) -> str | None:
    if module in FOUNDATION:
        return "foundation"
    in_domain = any(module.startswith(p + ".") for p in LAYERS["domain"])
    if in_domain and module.rsplit(".", 1)[-1].endswith("_io"):
        return "domain-io"
    for name, prefixes in LAYERS.items():
        if any(module == p or module.startswith(p + ".") for p in prefixes):
            return name
    return None


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports_of(path: Path) -> list[tuple[str, bool]]:
    """(imported module, at module level?) for every absolute import of a project package."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    top = {id(n) for n in tree.body}
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        for name in names:
            if name.split(".")[0] in (*PRODUCT, "simplant"):
                out.append((name, id(node) in top))
    return out


def violations(graph: dict[str, list[tuple[str, bool]]]) -> list[str]:
    """Every import in ``graph`` (module -> [(imported, at module level)]) that breaks the contract."""
    bad = []
    for mod, imports in sorted(graph.items()):
        src = layer_of(mod)
        for target, top_level in imports:
            if target.split(".")[0] == "simplant":
                if not any(mod == u or mod.startswith(u + ".") for u in SIMULATOR_USERS):
                    bad.append(f"{mod} imports the simulator ({target})")
                elif top_level:
                    bad.append(f"{mod} imports the simulator at module level ({target}); import it in the "
                               "simulation path only")
                continue
            dst = layer_of(target)
            if src is None or dst is None:
                bad.append(f"{mod} -> {target}: module outside every layer (add it to LAYERS)")
                continue
            if dst == "foundation" or dst == src:
                continue
            if src == "domain" and dst == "domain-io" and not top_level and (mod, target) in COMPAT_LAZY:
                continue
            if dst not in ALLOWED[src]:
                bad.append(f"{mod} ({src}) imports {target} ({dst})")
    return bad


def product_graph() -> dict[str, list[tuple[str, bool]]]:
    return {module_name(p): imports_of(p) for pkg in PRODUCT for p in sorted((ROOT / pkg).rglob("*.py"))
            if not p.is_relative_to(ROOT / "firmware_proto" / "c")}  # C codec build helpers


def test_layers_only_import_downward():
    bad = violations(product_graph())
    assert not bad, "layer contract broken (docs/architecture.md):\n" + "\n".join(bad)


@pytest.mark.parametrize("graph, expected", [
    ({"controller.geometry.kinematics": [("controller.devices.drive", True)]}, "imports controller.devices"),
    ({"controller.imaging.hdr": [("controller.io.images", False)]}, "imports controller.io"),
    ({"controller.devices.drive": [("controller.calibration.cycle.machine", True)]},
     "imports controller.calibration"),
    ({"controller.calibration.campaign.runner": [("controller.storage.db", True)]},
     "imports controller.storage"),
    ({"controller.calibration.campaign.runner": [("simplant.plant", False)]}, "imports the simulator"),
    ({"controller.commands.demo": [("simplant.plant", True)]}, "at module level"),
    ({"firmware_proto.codec": [("controller.devices.drive", True)]}, "imports controller.devices"),
])
def test_a_broken_layer_is_caught(graph, expected):
    bad = violations(graph)
    assert len(bad) == 1 and expected in bad[0]


def test_allowed_imports_pass():
    graph = {"controller.commands.demo": [("simplant.plant", False),
                                          ("controller.calibration.campaign.runner", True)],
             "controller.storage.db": [("controller.calibration.records.runs", True)],
             "controller.imaging.crf": [("controller.imaging.crf_io", False)],
             "controller.recognition.library_io": [("controller.io.images", True)]}
    assert violations(graph) == []


def test_simulator_is_not_part_of_the_product_schema():
    from controller.storage.db import CampaignStore

    store = CampaignStore(":memory:")
    cols = {row[1] for t in ("campaigns", "heliostat_runs", "measurements")
            for row in store._db.execute(f"PRAGMA table_info({t})").fetchall()}
    assert cols and not {c for c in cols if "true" in c or "truth" in c or c == "simulated"}


def test_modules_are_short_or_one_cohesive_thing():
    long = {module_name(p): n for pkg in (*PRODUCT, "simplant") for p in (ROOT / pkg).rglob("*.py")
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES}
    unexplained = {m: n for m, n in long.items() if m not in LONG_MODULES}
    assert not unexplained, f"modules over {MAX_LINES} lines: {unexplained}"


def simplant_graph() -> dict[str, list[tuple[str, bool]]]:
    return {module_name(p): imports_of(p) for p in sorted((ROOT / "simplant").rglob("*.py"))}


def plant_violations(graph: dict[str, list[tuple[str, bool]]]) -> list[str]:
    """Every import of the product's orchestration by the simulated plant."""
    return [f"{mod} imports {target}" for mod, imports in sorted(graph.items()) for target, _ in imports
            if any(target == o or target.startswith(o + ".") for o in ORCHESTRATION_OPERATIONS)]


def test_the_simulated_plant_assembles_no_orchestration():
    bad = plant_violations(simplant_graph())
    assert not bad, "the simulated plant must only provide devices and truth:\n" + "\n".join(bad)


@pytest.mark.parametrize("module", ORCHESTRATION_OPERATIONS)
def test_a_plant_that_imports_orchestration_is_caught(module):
    graph = {"simplant.harness": [(module, True), ("controller.calibration.records.observers", True)]}
    assert plant_violations(graph) == [f"simplant.harness imports {module}"]
