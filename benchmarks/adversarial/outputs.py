"""Issue 45's categories of values and outputs (see tally.py):

* ``outputs_on_refusal``: every refusal of tests/refusal_cases.py (commands with ``--out``,
  ``--db``, ``--plot``, ``--report``, JSON files) — refused in one line, exit 2, and the folder
  left exactly as it was (counted refused only then);
* ``odd_numbers``: numbers written with Unicode digits, superscripts, underscores, blanks,
  hex — through every numeric option of every command, the night and alarm numbers, durations,
  and a console step's integer fields;
* ``nan_in_json``: NaN/±Infinity reaching a JSON writer (refused naming where), in a JSON input
  (refused), and stored in a measurement an export reads (refused naming the row; no output);
* ``absurd_records``: PAINT records with values out of physical range read for a fit
  (refused naming the record and key), and stored measurements edited out of range (refit);
* ``console_values``: console bodies with duplicate ids, wrong types, empty or unknown ids,
  unknown fields — through the checks the endpoints use, shared with the CLI;
* ``console_routes``: unknown routes and methods through the console's error handlers: JSON.
"""

from __future__ import annotations

import contextlib
import io
import itertools
import json
import shutil
import sqlite3
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from adversarial.tally import Tally, _input_error  # noqa: E402
from controller.errors import InputError  # noqa: E402
from tests.refusal_cases import (  # noqa: E402
    ABSURD,
    ODD_NUMBERS,
    cases,
    make_folder,
    refused_cleanly,
    replaced,
    run,
    snapshot,
)

# Beyond the test's own values: the same categories with other members (held-out style).
MORE_ODD = ["৭", "߁", "𝟓", "⁵", "½", "Ⅻ", "1 000", "+-1", "1e", ".", "0b1", "１０", "1.5e٣", "\u00a01"]


def _refusal(name: str, argv: list[str], folder: Path):
    def fn():
        before = snapshot(folder)
        code, out, err = run(argv)
        return refused_cleanly(code, out, err, before, snapshot(folder))
    return fn


def outputs_on_refusal(folder: Path) -> dict:
    t = Tally()
    v = make_folder(folder)
    for name, argv in cases(v):
        t.case(name, _refusal(name, argv, folder), lambda why: why is None)
    return t.report()


def odd_numbers() -> dict:
    from test_cli_numbers import OPTIONS

    from controller.alarms.states import parse_duration
    from controller.cli import build_parser
    from controller.console.steps import _int
    from controller.io.text_numbers import is_ascii_index, parse_float, parse_int

    t = Tally()
    parser = build_parser()
    values = ODD_NUMBERS + MORE_ODD
    for (path, action), value in itertools.product(OPTIONS, values):
        if action.type.infinite and value == "1e999":
            continue  # an option that takes inf takes it however spelled
        n = action.nargs if isinstance(action.nargs, int) else 1
        argv = [*path, action.option_strings[0], *([value] * n)]

        def parse(a=argv):
            with contextlib.redirect_stderr(io.StringIO()) as err:
                try:
                    parser.parse_args(a)
                except SystemExit as exc:
                    return exc.code, err.getvalue()
            return 0, ""
        t.case(" ".join(argv), parse, lambda o, opt=action.option_strings[0]:
               isinstance(o, tuple) and o[0] == 2 and opt in o[1] and len(o[1].strip().splitlines()) == 1)
    for value in values:
        t.case(f"parse_int {value!r}", lambda x=value: parse_int(x, "n"), _input_error)
        if value not in ("1e999", "nan"):  # parse_float returns those for the caller's range check
            t.case(f"parse_float {value!r}", lambda x=value: parse_float(x, "x"), _input_error)
        if not value.strip().isascii():  # (blanks around a number: still a duration)
            t.case(f"duration {value!r}", lambda x=value: parse_duration(f"{x}h"), _input_error)
        t.case(f"index {value!r}", lambda x=value: is_ascii_index(x) or InputError("not an index"),
               _input_error)
        t.case(f"console az_steps {value!r}", lambda x=value: _int({"az_steps": x}, "az_steps"), _input_error)
    for value in (1.5, True, None, [1], {"a": 1}, "1e3"):
        t.case(f"console az_steps {value!r}", lambda x=value: _int({"az_steps": x}, "az_steps"), _input_error)
    return t.report()


def nan_in_json(folder: Path) -> dict:
    from controller.io.json_files import NotJsonError, dumps_json, parse_json

    t = Tally()
    bad = [float("nan"), float("inf"), -float("inf")]
    shapes = [lambda x: x, lambda x: {"a": x}, lambda x: [1, 2, x], lambda x: {"a": [{"b": (0, x)}]},
              lambda x: {"error_mrad": x, "ok": True}]
    for x, shape in itertools.product(bad, shapes):
        obj = shape(x)
        t.case(f"dumps {obj!r}", lambda o=obj: dumps_json(o),
               lambda r: isinstance(r, NotJsonError) and "\n" not in str(r) and "JSON cannot hold" in str(r))
    for text in ('{"a": NaN}', '[Infinity]', '{"x": -Infinity}', '{"a": [1, {"b": NaN}]}'):
        t.case(text, lambda s=text: parse_json(s, "in.json"),
               lambda r: _input_error(r) and "in.json" in str(r))
    # A measurement stored with ±inf: export refuses naming the row, writes nothing.
    d = folder / "nan"
    d.mkdir()
    v = make_folder(d)
    for col, value in itertools.product(("error_mrad", "centroid_e", "source_az_deg", "match_distance"),
                                        ("9e999", "-9e999")):
        db = d / f"inf-{col}-{value[0]}.db"
        shutil.copy(v["db"], db)
        with sqlite3.connect(db) as c:
            c.execute(f"UPDATE measurements SET {col}={value} WHERE id=(SELECT MIN(id) FROM measurements)")
        argv = ["export", "--db", str(db), "--format", "paint", "--out", str(d / "e")]
        t.case(f"export {col}={value}", _refusal(col, argv, d), lambda why: why is None)
    return t.report()


def absurd_records(folder: Path) -> dict:
    from controller.geometry.paint_io import read_paint_set

    t = Tally()
    d = folder / "absurd"
    d.mkdir()
    v = make_folder(d)
    base = json.loads(Path(v["rec"]).read_text())
    more = ABSURD + [("lat-neg", ["focal_spot", "UTIS", 0], -90.5),
                     ("lon-181", ["focal_spot", "UTIS", 1], 181.0),
                     ("spot-str", ["focal_spot", "UTIS", 0], "50.9"),
                     ("el-neg", ["motor_position", "axis_1_motor_position"], -1.0),
                     ("az-huge", ["motor_position", "axis_2_motor_position"], 1e300),
                     ("sun-el-91", ["sun_elevation"], 91.0), ("sun-az-str", ["sun_azimuth"], "south"),
                     ("spot-2", ["focal_spot", "UTIS"], [50.9, 6.38]),
                     ("spot-1km", ["focal_spot", "UTIS", 0], 50.9224)]
    for name, path, value in more:
        f = d / f"more-{name}.json"
        f.write_text(json.dumps(replaced(base, path, value)))
        t.case(name, lambda p=f: read_paint_set([str(p), v["rec"]], v["props"], v["towers"]),
               lambda r, p=f: _input_error(r) and str(p) in str(r))
    for col, value in (("az_steps", 10**12), ("el_steps", -5), ("centroid_n", 1e7), ("source_u", 3.0),
                       ("aim_e", -1e6)):
        db = d / f"edited-{col}.db"
        shutil.copy(v["db"], db)
        with sqlite3.connect(db) as c:
            c.execute(f"UPDATE measurements SET {col}=? WHERE id=(SELECT MIN(id) FROM measurements)",
                      (value,))
        argv = ["model", "refit", "--config", v["pcfg"], "--db", str(db)]
        t.case(f"refit {col}={value}", _refusal(col, argv, d), lambda why: why is None)
    return t.report()


def console_values() -> dict:
    from controller.commands._id_lists import campaign_name, id_list
    from controller.console.backend import only_keys

    known = {"H01", "H02", "H03"}

    def lookup(hid: str) -> str:
        if hid not in known:
            raise InputError(f"unknown heliostat {hid!r}")
        return hid
    t = Tally()
    lists = [["H01", "H01"], ["H02", "H01", "H02"], "H01", ["H01", 2], [None], [["H01"]], {"H01": 1}, [""],
             [" "], ["H04"], ["h01"], ["H01\n"], ["H01\x00"], 7, True, []]
    for ids in lists:
        t.case(f"heliostats {ids!r}", lambda x=ids: id_list(x, "heliostats", lookup), _input_error)
    for name in (["a"], "", " ", "x\ny", "\x1b[2J", "a" * 201, 3, {"n": 1}):
        t.case(f"name {str(name)[:20]!r}", lambda x=name: campaign_name(x, "name"), _input_error)
    for body, allowed in (({"heliostats": ["H01"], "strategy": "x"}, ("heliostats",)), ({"now": 1}, ()),
                          ({"az_steps": 1, "el_steps": 0, "speed": 9}, ("az_steps", "el_steps")),
                          ({"user": "a", "password": "b", "role": "engineer"}, ("user", "password"))):
        t.case(f"body {body}", lambda b=body, a=allowed: only_keys(b, a, "request"), _input_error)
    return t.report()


def console_routes() -> dict:
    from starlette.applications import Starlette
    from starlette.exceptions import HTTPException
    from starlette.responses import JSONResponse
    from starlette.routing import Route
    from starlette.testclient import TestClient

    from controller.console.app import _http_error, _server_error

    async def ok(request):
        return JSONResponse({"ok": True})

    async def boom(request):
        raise RuntimeError("a bug")
    app = Starlette(routes=[Route("/api/plant", ok), Route("/api/x/{n:int}", ok), Route("/boom", boom)],
                    exception_handlers={HTTPException: _http_error, Exception: _server_error})
    t = Tally()
    with TestClient(app, raise_server_exceptions=False) as client:
        for method, path in (("GET", "/nope"), ("POST", "/api/nothing"), ("GET", "/api/x/abc"),
                             ("DELETE", "/api/plant"), ("PUT", "/api/plant"), ("PATCH", "/api/x/1"),
                             ("GET", "/%ff"), ("GET", "/" + "a" * 5000), ("GET", "/boom")):
            def call(m=method, p=path):
                r = client.request(m, p)
                return r.status_code, r.headers.get("content-type", ""), r.text
            t.case(f"{method} {path[:30]}", call, _json_refusal)
    return t.report()


def _json_refusal(o: tuple[int, str, str]) -> bool:
    return o[0] >= 400 and o[1].startswith("application/json") and json.loads(o[2])["ok"] is False


def categories(folder: Path) -> dict[str, dict]:
    d = folder / "outputs"
    (d / "refusals").mkdir(parents=True)
    return {"outputs_on_refusal": outputs_on_refusal(d / "refusals"), "odd_numbers": odd_numbers(),
            "nan_in_json": nan_in_json(d), "absurd_records": absurd_records(d),
            "console_values": console_values(), "console_routes": console_routes()}
