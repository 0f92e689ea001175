"""Refusals of the commands that write outputs (``--out``, ``--db``, ``--plot``, ``--report``, JSON
files, reports), and a folder to run them in: each must exit 2 in one line and leave the folder
as it was — nothing new, nothing changed (issue 45). Used by tests/test_refusals_write_nothing.py
and benchmarks/adversarial/outputs.py.

The cases are built per category from a few bad values, not listed one by one: an output whose
folder does not exist, an output that exists and is another kind of file (empty, a folder,
another program's database, an old database whose upgrade fails), bad values (duplicate ids,
numbers that are not ASCII, absurd record values) beside a valid output.
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import io
import json
import re
import shutil
import sqlite3
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
AA39 = REPO / "tests" / "data" / "real" / "aa39"
PAINT = REPO / "tests" / "data" / "real" / "paint-field"
ODD_NUMBERS = ["²", "١", "１", "1_0", " 1", "0x1", "1e999", "nan", "٣.٥", "1\u200b"]


def make_folder(d: Path) -> dict[str, str]:
    """Inputs and existing outputs in ``d``: a one-heliostat configuration, a database with a
    PAINT heliostat's measurements (and its configuration), an empty file, an empty folder,
    another program's database, an old heliocal database whose upgrade fails, PAINT records
    with absurd values. Databases in rollback-journal mode, so reading them adds no side file."""
    import yaml

    from controller.cli import main
    from controller.commands.common import PACKAGED_CONFIG
    from controller.storage.schema import MIGRATIONS

    v = {"cfg": d / "one.yaml", "db": d / "p.db", "pcfg": d / "p.config.yaml", "empty": d / "empty.db",
         "folder": d / "folder", "foreign": d / "foreign.db", "old": d / "old.db", "paint": d / "paint",
         "rec": AA39 / "AA39-calibration-properties_1.json", "props": AA39 / "AA39-heliostat-properties.json",
         "towers": AA39 / "tower-measurements.json"}
    plant = yaml.safe_load(Path(PACKAGED_CONFIG).read_text())
    plant["heliostats"] = plant["heliostats"][:1]
    v["cfg"].write_text(yaml.safe_dump(plant, sort_keys=False))
    shutil.copytree(PAINT / "BK20", v["paint"] / "BK20")
    for name in ("tower-measurements.json", "timestamps.json"):
        shutil.copy(PAINT / name, v["paint"] / name)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()) as err:
        assert main(["import", "paint", str(v["paint"]), "--db", str(v["db"])]) == 0, err.getvalue()
    v["empty"].touch()
    v["folder"].mkdir()
    with sqlite3.connect(v["foreign"]) as c:
        c.execute("CREATE TABLE notes (t TEXT)")
        c.execute("PRAGMA user_version=3")  # another program's own versioning
    with sqlite3.connect(v["old"]) as c:  # heliocal v1 plus a table a later migration creates
        c.executescript(MIGRATIONS[0])
        later = re.findall(r"CREATE TABLE (?:IF NOT EXISTS )?(\w+)", "".join(MIGRATIONS[1:]))[-1]
        c.execute(f"CREATE TABLE {later} (x)")
        c.execute("PRAGMA user_version=1")
    for db in (v["db"], v["foreign"], v["old"]):
        with sqlite3.connect(db) as c:
            c.execute("PRAGMA journal_mode=DELETE")
    base = json.loads(v["rec"].read_text())
    for name, path, value in ABSURD:
        (d / f"absurd-{name}.json").write_text(json.dumps(replaced(base, path, value)))
    return {k: str(p) for k, p in v.items()}


def replaced(record: dict, path: list, value) -> dict:
    """A copy of ``record`` with the value at ``path`` (keys and indices) replaced by ``value``."""
    rec = copy.deepcopy(record)
    node = rec
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value
    return rec


# A PAINT record's values out of any physical range (model fit/validate/import refuse them).
ABSURD = [("lat91", ["focal_spot", "UTIS", 0], 91.0), ("lon-far", ["focal_spot", "UTIS", 1], 120.0),
          ("alt", ["focal_spot", "UTIS", 2], 1e7),
          ("el-steps", ["motor_position", "axis_1_motor_position"], 1e12),
          ("az-steps", ["motor_position", "axis_2_motor_position"], -5.0e6),
          ("sun-az", ["sun_azimuth"], 7200.0), ("sun-el", ["sun_elevation"], -3.0),
          ("spot-null", ["focal_spot", "UTIS"], None)]


def cases(v: dict[str, str]) -> list[tuple[str, list[str]]]:
    """(name, argv) of every refusal; ``{missing}``: a folder that does not exist."""
    missing = str(Path(v["folder"]).parent / "no-such-folder" / "sub")
    c, db, pcfg = v["cfg"], v["db"], v["pcfg"]
    out: list[tuple[str, list[str]]] = []
    fit = ["--heliostat-properties", v["props"], "--towers", v["towers"]]
    d = Path(v["folder"]).parent
    for kind in ("missing", "folder", "foreign", "old"):  # (an empty file is a new database: not refused)
        target = f"{missing}/n.db" if kind == "missing" else v[kind]
        run = ["--config", c, "--db", target, "--simulate"]
        out += [(f"campaign run --db {kind}", ["campaign", "run", *run]),
                (f"campaign night --db {kind}", ["campaign", "night", *run]),
                (f"alarms list --db {kind}", ["alarms", "list", "--db", target]),
                (f"users remove --db {kind}", ["users", "remove", "nobody", "--db", target]),
                (f"model refit --db {kind}", ["model", "refit", "--config", pcfg, "--db", target])]
    for kind in ("missing", "empty", "folder", "foreign", "old", "db"):
        target = f"{missing}/new.db" if kind == "missing" else v[kind]
        out.append((f"reprocess --out {kind}", ["reprocess", "--db", db, "--out", target, "--workers", "1"]))
    new = ["--config", c, "--db", str(d / "n.db"), "--simulate"]
    for bad in ("H01,H01", "H01,,H01", "H99", ",", "H01, H01"):
        out += [(f"campaign run --heliostats {bad}", ["campaign", "run", *new, "--heliostats", bad]),
                (f"campaign night --heliostats {bad}", ["campaign", "night", *new, "--heliostats", bad]),
                (f"model refit --heliostats {bad}", ["model", "refit", "--config", pcfg, "--db", db,
                                                     "--heliostats", bad])]
    for n in ODD_NUMBERS:
        out += [(f"report --night {n!r}", ["report", "campaign", "--db", db, "--out", str(d / "r"),
                                           "--night", n]),
                (f"campaign run --seed {n!r}", ["campaign", "run", *new, "--seed", n]),
                (f"demo --nights {n!r}", ["demo", "--config", c, "--nights", n, "--out", str(d / "demo")]),
                (f"alarms ack {n!r}", ["alarms", "ack", n, "--db", db]),
                (f"alarms shelve --for {n!r}h", ["alarms", "shelve", "1", "--for", f"{n}h", "--db", db]),
                (f"sim field --heliostats {n!r}", ["sim", "field", "--out", str(d / "f"), "--heliostats", n])]
    out += [("export --out missing", ["export", "--db", db, "--format", "paint", "--out", f"{missing}/e"]),
            ("export --campaign unknown", ["export", "--db", db, "--format", "paint", "--out", str(d / "e"),
                                           "--campaign", "nope"]),
            ("export models --out missing", ["export", "models", "--db", db, "--format", "json", "--out",
                                             f"{missing}/m.json"]),
            ("export tracking-table --day", ["export", "tracking-table", "--config", pcfg, "--db", db,
                                             "--day", "2026-13-01", "--out", str(d / "t.csv")]),
            ("report --out missing", ["report", "campaign", "--db", db, "--out", f"{missing}/r"]),
            ("report --campaign unknown", ["report", "campaign", "--db", db, "--out", str(d / "r"),
                                           "--campaign", "nope"]),
            ("campaign run --report missing", ["campaign", "run", "--config", c, "--db", str(d / "n.db"),
                                               "--simulate", "--report", f"{missing}/r"]),
            ("campaign run --name blank", ["campaign", "run", "--config", c, "--db", str(d / "n.db"),
                                           "--simulate", "--name", " "]),
            ("campaign night without lamps", ["campaign", "night", "--config", c, "--db", str(d / "n.db")]),
            ("campaign flags --clear twice", ["campaign", "flags", "--db", db, "--clear", "BK20,BK20"]),
            ("users add --password-file missing", ["users", "add", "x", "--role", "viewer", "--password-file",
                                                   f"{missing}/pw", "--db", str(d / "u.db")]),
            ("audit --since", ["audit", "--since", "yesterday", "--db", db]),
            ("opcua --endpoint", ["opcua", "--config", pcfg, "--db", str(d / "o.db"), "--endpoint", "http://x"]),
            ("console --token-file missing", ["console", "--config", c, "--db", str(d / "c.db"),
                                              "--token-file", f"{missing}/t", "--port", "0"]),
            ("demo --out missing", ["demo", "--config", c, "--out", f"{missing}/d"]),
            ("sim field --out file", ["sim", "field", "--out", v["empty"], "--heliostats", "2"]),
            ("model prior --out missing", ["model", "prior", v["rec"], "--out", f"{missing}/p.json"])]
    for name, _, _ in ABSURD:
        rec = str(d / f"absurd-{name}.json")
        out += [(f"model fit {name}", ["model", "fit", rec, v["rec"], *fit, "--out", str(d / "m.json")]),
                (f"model validate {name}", ["model", "validate", rec, v["rec"], v["rec"], *fit, "--plot",
                                            str(d / "plots")])]
    return out


def snapshot(d: Path) -> dict[str, str]:
    """Every path under ``d`` with a digest of its content (a database's: its rows, so that a
    reader's change of journal mode is not counted)."""
    out = {}
    for p in sorted(d.rglob("*")):
        rel = str(p.relative_to(d))
        if p.is_dir():
            out[rel] = "folder"
        elif p.suffix == ".db" and p.stat().st_size:
            try:
                with contextlib.closing(sqlite3.connect(f"file:{p}?mode=ro", uri=True)) as c:
                    out[rel] = hashlib.sha256("\n".join(c.iterdump()).encode()).hexdigest()
            except sqlite3.Error:
                out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
        else:
            out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def run(argv: list[str]) -> tuple[int, str, str]:
    """``heliocal argv`` in this process: (exit status, stdout, stderr)."""
    from controller.cli import main

    with contextlib.redirect_stdout(io.StringIO()) as o, contextlib.redirect_stderr(io.StringIO()) as e:
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code
        except BaseException as exc:  # noqa: BLE001 - a traceback is what the check reports
            import traceback

            e.write("Traceback\n" + "".join(traceback.format_exception(exc)))
            code = -1
    return code, o.getvalue(), e.getvalue()


def refused_cleanly(code: int, out: str, err: str, before: dict, after: dict) -> str | None:
    """None when the run ended as a refusal must, else what was wrong."""
    lines = [ln for ln in err.splitlines() if not ln.startswith("heliocal: using configuration")]
    if "Traceback" in out + err:
        return "traceback: " + err[-300:]
    if code != 2:
        return f"exit {code}: {err[-200:]}"
    if len(lines) != 1:
        return f"{len(lines)} lines on stderr: {err[-200:]}"
    new = sorted(set(after) - set(before))
    changed = sorted(k for k in before if after.get(k) != before[k])
    if new or changed:
        return f"left new {new} changed {changed}"
    return None
