"""The layer contract of docs/architecture.md, checked on every import of the product.

Layers from the wire up: wire (``firmware_proto``) → drivers (``controller.devices``) → pure
domain (``geometry``, ``imaging``, ``flux``, ``recognition``) → orchestration
(``calibration``) → interfaces (``commands``, ``reports``, ``storage``, ``console``, ``cli``).
Every import — at module level or inside a function — must point to the importer's own layer
or one allowed below it. The simulated plant (``simplant``) sits outside: the product never
imports it, except the one command module that wires it (``controller.commands.simulated``) and
``heliocal sim``. No import cycles anywhere, and no package folder over 20 modules.
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
              "controller.alarm_config", "controller.search_config"}

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
COMPAT_LAZY = {("controller.imaging.crf", "controller.imaging.crf_yaml_io")}

# The one command module outside ``heliocal sim`` that wires the simulated plant (it imports it
# lazily, in the --simulate paths); every other command asks it (docs/architecture.md).
SIMULATOR_USERS = ("controller.commands.simulated", "controller.commands.sim")

# The product's orchestration the simulated plant must never import: it provides devices and
# truth (like ophyd.sim), it does not assemble campaigns, nights or lamp changes itself.
ORCHESTRATION_OPERATIONS = ("controller.calibration.campaign.runner",
                            "controller.calibration.night.passes",
                            "controller.calibration.night.planned",
                            "controller.calibration.campaign.lamp_change",
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
    ({"controller.commands.simulated": [("simplant.plant", True)]}, "at module level"),
    ({"controller.commands.campaigns.demo": [("simplant.settings", False)]}, "imports the simulator"),
    ({"firmware_proto.codec": [("controller.devices.drive", True)]}, "imports controller.devices"),
])
def test_a_broken_layer_is_caught(graph, expected):
    bad = violations(graph)
    assert len(bad) == 1 and expected in bad[0]


def test_allowed_imports_pass():
    graph = {"controller.commands.simulated": [("simplant.plant", False),
                                          ("controller.calibration.campaign.runner", True)],
             "controller.storage.db": [("controller.calibration.records", True)],
             "controller.imaging.crf": [("controller.imaging.crf_yaml_io", False)],
             "controller.recognition.library_io": [("controller.io.images", True)]}
    assert violations(graph) == []


def test_simulator_is_not_part_of_the_product_schema():
    from controller.storage.db import CampaignStore

    store = CampaignStore(":memory:")
    cols = {row[1] for t in ("campaigns", "heliostat_runs", "measurements")
            for row in store._db.execute(f"PRAGMA table_info({t})").fetchall()}
    assert cols and not {c for c in cols if "true" in c or "truth" in c or c == "simulated"}


def project_modules() -> dict[str, Path]:
    """Every module of the product and the simulated plant, by dotted name."""
    return {module_name(p): p for pkg in (*PRODUCT, "simplant") for p in sorted((ROOT / pkg).rglob("*.py"))}


def module_graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    """module -> the project modules it imports: module level or in a function (under
    TYPE_CHECKING too), absolute or relative; ``from pkg import name`` is an import of ``pkg``
    (its ``__init__``) and, when ``pkg.name`` is a module, of that module too."""
    def known(name: str) -> str | None:
        parts = name.split(".")
        while parts and ".".join(parts) not in modules:
            parts.pop()
        return ".".join(parts) or None

    graph: dict[str, set[str]] = {}
    for mod, path in modules.items():
        package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
        edges: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                edges.update(filter(None, (known(a.name) for a in node.names)))
            elif isinstance(node, ast.ImportFrom):
                base = package.split(".")[: len(package.split(".")) - node.level + 1] if node.level else []
                source = ".".join(base + ([node.module] if node.module else []))
                edges.update(filter(None, [known(source)] + [f"{source}.{a.name}" for a in node.names
                                                             if f"{source}.{a.name}" in modules]))
        graph[mod] = edges - {mod}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles of ``graph``: its strongly connected components of more than one module
    (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while (w := stack.pop()) != v:
                component.append(w)
            if component:
                found.append(sorted([v, *component]))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_cycles():
    found = cycles(module_graph(project_modules()))
    assert not found, "import cycles (move the shared piece down):\n" + "\n".join(map(" <-> ".join, found))


@pytest.mark.parametrize("graph, cycle", [
    ({"controller.imaging.crf": {"controller.imaging.crf_io"},
      "controller.imaging.crf_io": {"controller.imaging.crf"}},
     ["controller.imaging.crf", "controller.imaging.crf_io"]),
    ({"simplant.plant": {"simplant.poses"}, "simplant.poses": {"simplant.safety"},
      "simplant.safety": {"simplant.plant"}, "simplant.truth": set()},
     ["simplant.plant", "simplant.poses", "simplant.safety"]),
    ({"controller.commands.campaigns.demo": {"controller.commands.simulated"},
      "controller.commands.simulated": {"controller.commands.campaigns._demo_coarse"},
      "controller.commands.campaigns._demo_coarse": {"controller.commands.campaigns.demo"}},
     ["controller.commands.campaigns._demo_coarse", "controller.commands.campaigns.demo",
      "controller.commands.simulated"]),
])
def test_an_added_cycle_is_caught(graph, cycle):
    assert cycles(graph) == [cycle]


def test_an_added_cycle_in_the_code_is_caught(tmp_path):
    """A function-level import back into the importer's importer, in real files, is a cycle."""
    (tmp_path / "a.py").write_text("from controller.b import f\n")
    (tmp_path / "b.py").write_text("def f():\n    from controller.a import g\n")
    (tmp_path / "c.py").write_text("from . import a\n")
    graph = module_graph({"controller.a": tmp_path / "a.py", "controller.b": tmp_path / "b.py",
                          "controller.c": tmp_path / "c.py"})
    assert graph["controller.c"] == {"controller.a"}
    assert cycles(graph) == [["controller.a", "controller.b"]]


def simulator_importers(graph: dict[str, set[str]]) -> list[str]:
    """The command modules outside ``heliocal sim`` that import the simulated plant."""
    return sorted(m for m, edges in graph.items()
                  if m.startswith("controller.commands.")
                  and not (m + ".").startswith("controller.commands.sim.")
                  and any(e == "simplant" or e.startswith("simplant.") for e in edges))


def test_the_simulated_field_is_wired_in_one_command_module():
    assert simulator_importers(module_graph(project_modules())) == ["controller.commands.simulated"]


def test_a_second_simulator_importer_is_caught():
    graph = {"controller.commands.simulated": {"simplant.plant"},
             "controller.commands.campaigns.demo": {"simplant.settings"},
             "controller.commands.sim.plant": {"simplant.plant"}}
    assert simulator_importers(graph) == ["controller.commands.campaigns.demo",
                                          "controller.commands.simulated"]


def private_command_imports(path: Path) -> list[str]:
    """The ``controller.commands._*`` modules (private helpers) a file imports."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
            [node.module, *(f"{node.module}.{a.name}" for a in node.names)] \
            if isinstance(node, ast.ImportFrom) and node.module else []
        out += [n for n in names if n.startswith("controller.commands.")
                and any(part.startswith("_") for part in n.split(".")[2:])]
    return out


def test_benchmarks_use_public_entry_points_only():
    bad = {p.name: found for p in sorted((ROOT / "benchmarks").glob("*.py"))
           if (found := private_command_imports(p))}
    assert not bad, f"benchmarks importing private command modules: {bad}"


@pytest.mark.parametrize("source", ["from controller.commands._field import open_store\n",
                                    "def f():\n    import controller.commands.campaigns._night\n",
                                    "from controller.commands import _common\n"])
def test_a_benchmark_importing_a_private_command_module_is_caught(tmp_path, source):
    (tmp_path / "bench_x.py").write_text(source)
    assert private_command_imports(tmp_path / "bench_x.py")


MAX_FOLDER_MODULES = 20


def test_no_package_folder_over_20_modules():
    folders = {p.parent for pkg in (*PRODUCT, "simplant") for p in (ROOT / pkg).rglob("*.py")}
    big = {str(f.relative_to(ROOT)): n for f in folders
           if (n := len(list(f.glob("*.py")))) > MAX_FOLDER_MODULES}
    assert not big, f"package folders over {MAX_FOLDER_MODULES} modules (split them by subject): {big}"


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
    graph = {"simplant.harness": [(module, True), ("controller.calibration.campaign.observers", True)]}
    assert plant_violations(graph) == [f"simplant.harness imports {module}"]
