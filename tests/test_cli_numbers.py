"""Every numeric option of every command has a stated range checked before any work (issue
27): walking the argparse tree, an option typed plain ``int``/``float`` fails this test; every
``Number`` option refuses NaN, ±inf, ±1e308 and the first value past each bound with exit 2 and
a line naming the option. The commands' own checks (a --out that is a file, an ambient brighter
than the receiver, an image without positive signal) are tested beside them."""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from controller.cli import build_parser
from controller.commands._numbers import Number
from tests.conftest import run_cli

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = REPO / "docs" / "examples"


def _numeric_options():
    def walk(parser, path):
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, sub in a.choices.items():
                    yield from walk(sub, [*path, name])
            elif a.type in (int, float) or isinstance(a.type, Number):
                yield path, a
    yield from walk(build_parser(), [])


OPTIONS = list(_numeric_options())


def test_every_numeric_option_has_a_range():
    plain = [f"heliocal {' '.join(p)} {a.option_strings[0]}" for p, a in OPTIONS
             if not isinstance(a.type, Number)]
    assert not plain, "numeric options without a range (type=Number(...)): " + ", ".join(plain)
    assert len(OPTIONS) >= 80


def _bad_values(n: Number) -> list[str]:
    out = ["nan", "-inf", "1e308", "-1e308", "x", "١", "１", "²", "1_0"]  # int() takes ١, １ and 1_0
    if not n.infinite:
        out.append("inf")
    step = 1 if n.integer else max(abs(n.lo), abs(n.hi), 1.0) * 1e-9
    out.append(repr(n.lo if n.lo_open else n.lo - step) if not n.integer else str(int(n.lo) - 1))
    out.append(repr(n.hi if n.hi_open else n.hi + step) if not n.integer else str(int(n.hi) + 1))
    return out


@pytest.mark.parametrize("path,action", OPTIONS,
                         ids=[f"{' '.join(p)} {a.option_strings[0]}" for p, a in OPTIONS])
def test_out_of_range_values_exit_2_naming_the_option(path, action):
    n: Number = action.type
    parser = build_parser()
    for value in _bad_values(n):
        values = [value] * (action.nargs if isinstance(action.nargs, int) else 1)
        err = io.StringIO()
        with contextlib.redirect_stderr(err), pytest.raises(SystemExit) as exc:
            parser.parse_args([*path, action.option_strings[0], *values])
        assert exc.value.code == 2
        last = err.getvalue().strip().splitlines()[-1]
        assert f"argument {action.option_strings[0]}" in last or f"{action.option_strings[0]}" in last, last
    ok = n.hi if n.integer else (n.lo + n.hi) / 2
    assert n(str(ok)) == ok


def test_the_range_text():
    assert Number(0, 1, lo_open=True).range_text() == "(0, 1]"
    assert Number(0, 1e6, lo_open=True, infinite=True)("inf") == math.inf


def test_merge_refuses_absurd_exposures_before_reading(tmp_path):
    code, _, err = run_cli(["merge", str(EXAMPLES / "amb.png"), str(EXAMPLES / "rx.png"),
                         "--exposures", "1e-300", "1e300", "--out", str(tmp_path / "hdr.npy")])
    assert code == 2 and "--exposures" in err and not any(tmp_path.iterdir())


def test_glare_points_are_bounded_before_allocating():
    code, _, err = run_cli(["glare", "--geometry", "heliostat", "--points", "1000000000"])
    assert code == 2 and "--points: 1000000000 is outside [2, 100000]" in err


def test_demo_seed_and_an_existing_out_file(tmp_path):
    code, _, err = run_cli(["demo", "--seed", "-1", "--out", str(tmp_path / "d")])
    assert code == 2 and "--seed: -1 is outside" in err
    f = tmp_path / "a-file"
    f.write_text("keep me")
    code, _, err = run_cli(["demo", "--heliostats", "1", "--aim-only", "--out", str(f)])
    assert code == 2 and f"--out {f}: exists and is not a folder" in err, err
    assert f.read_text() == "keep me"


def test_flux_with_an_ambient_brighter_than_the_receiver_is_refused(tmp_path):
    code, _, err = run_cli(["flux", str(EXAMPLES / "amb.png"), "--ambient", str(EXAMPLES / "rx.png"),
                         "--sun", str(EXAMPLES / "sun.png"), "--dni", "900", "--reflectivity", "0.9",
                         "--sun-transmittance", "0.01", "--out", str(tmp_path / "f.npy")])
    assert code == 2, err
    assert "ambient" in err and "brighter" in err and not any(tmp_path.iterdir())


def test_beam_on_an_image_without_positive_signal_says_so(tmp_path):
    img = -np.abs(np.random.default_rng(0).normal(100, 10, (64, 64)))
    p = tmp_path / "negated.npy"
    np.save(p, img)
    code, out, err = run_cli(["beam", str(p)])
    assert code == 2 and f"{p}: no positive signal" in err, err + out


def test_a_sample_as_a_subprocess():
    r = subprocess.run([sys.executable, "-m", "controller.cli", "glare", "--geometry", "heliostat",
                        "--sun-transmittance", "2"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "argument --sun-transmittance: 2 is outside (0, 1]" in r.stderr
    assert "Traceback" not in r.stderr
