"""The simulated truth (``simplant/truth.py``) is written independently of the controller.

The fit's tests compare the controller's tracking model with a heliostat it did not generate;
that comparison means something only if the truth shares no code with the model. Checked two
ways: statically (every import statement, at module level or inside a function, followed
through the other simplant modules it reaches) and at run time (importing it in a fresh
interpreter loads no ``controller`` module). Twin tests show each check catches a module that
does import the controller.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TRUTH = ROOT / "simplant" / "truth.py"


def imported_modules(source: str, package: str) -> set[str]:
    """Every module an import statement in ``source`` names (absolute; relative ones resolved
    against ``package``), wherever the statement is; plus ``__import__``/``import_module``
    calls with a literal name."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out.add(mod)
            out.update(f"{mod}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
            name = getattr(node.func, "id", getattr(node.func, "attr", ""))
            if name in ("__import__", "import_module") and isinstance(node.args[0].value, str):
                out.add(node.args[0].value)
    return out


def controller_imports(path: Path, root: Path = ROOT, package: str = "simplant") -> set[str]:
    """``controller`` modules that ``path`` imports, directly or through the ``package``
    modules (under ``root``) it imports."""
    seen: set[Path] = set()
    found: set[str] = set()
    todo = [path]
    while todo:
        p = todo.pop()
        if p in seen:
            continue
        seen.add(p)
        for mod in imported_modules(p.read_text(encoding="utf-8"), package):
            if mod == "controller" or mod.startswith("controller."):
                found.add(mod)
            elif mod.startswith(f"{package}."):
                parts = mod.split(".")
                for cand in (root.joinpath(*parts).with_suffix(".py"), root.joinpath(*parts, "__init__.py")):
                    if cand.is_file():
                        todo.append(cand)
    return found


def test_truth_imports_nothing_from_the_controller():
    assert TRUTH.is_file()
    assert controller_imports(TRUTH) == set()


def test_the_static_check_catches_a_module_that_imports_the_controller(tmp_path):
    """Twin: the same check on modules that do reach the controller, in each way it looks for."""
    for source in ("from controller.geometry.kinematics import HeliostatKinematics\n",
                   "import numpy as np\n\ndef f():\n    import controller.geometry.error_model as em\n",
                   "import importlib\nm = importlib.import_module('controller.geometry')\n",
                   "from controller import errors\n"):
        bad = tmp_path / "bad_truth.py"
        bad.write_text(source)
        assert controller_imports(bad) != set(), source
    assert controller_imports(ROOT / "simplant" / "plant.py")  # a real simplant module that does


def test_the_static_check_follows_simplant_imports(tmp_path):
    """Twin: a truth that reaches the controller only through another simplant module."""
    pkg = tmp_path / "simplant"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "helper.py").write_text("from controller.geometry.vectors import unit\n")
    (pkg / "truth.py").write_text("from simplant.helper import unit\n")
    assert controller_imports(pkg / "truth.py", tmp_path) == {"controller.geometry.vectors",
                                                              "controller.geometry.vectors.unit"}


LOADED = "import sys\nimport {m}\nprint(sorted(n for n in sys.modules if n.split('.')[0] == 'controller'))"


def _controller_modules_loaded_by(module: str, cwd: Path) -> str:
    res = subprocess.run([sys.executable, "-c", LOADED.format(m=module)], capture_output=True, text=True,
                         cwd=cwd, timeout=60, check=False)
    assert res.returncode == 0, res.stderr
    return res.stdout.strip()


def test_importing_the_truth_loads_no_controller_module():
    assert _controller_modules_loaded_by("simplant.truth", ROOT) == "[]"


def test_the_run_time_check_sees_a_module_that_loads_the_controller():
    """Twin: a simplant module that does use the controller (the plant) shows up."""
    assert "controller.geometry" in _controller_modules_loaded_by("simplant.plant", ROOT)
