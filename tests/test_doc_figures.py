"""The figures the README and the docs quote agree with the benchmark output they come from
(``benchmarks/results/*.json``, recorded by ``benchmarks/record.py``; marked in the Markdown,
``benchmarks/figures.py``). Nothing heavy runs here: the recorded JSON is read."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "benchmarks"))

import figures  # noqa: E402


def test_every_marked_figure_agrees_with_its_recorded_source():
    found = figures.check(REPO)
    assert len(found) >= 20, "the docs mark fewer figures than they quote"
    bad = [str(f) for f in found if f.problem]
    assert not bad, "figures that disagree with their source:\n" + "\n".join(bad)


def test_every_figure_of_the_readme_headline_table_is_marked():
    text = (REPO / "README.md").read_text(encoding="utf-8")
    table = text.split("## Headline results", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in table.splitlines() if line.startswith("| ") and "---" not in line][1:]
    assert len(rows) >= 6
    for row in rows:
        cell = row.split("|")[1]
        numbers = figures.NUMBER.findall(figures.MARKER.sub(" ", cell))
        marks = figures.MARKER.findall(cell)
        assert marks and len(numbers) == len(marks), f"unmarked figure in the headline: {cell.strip()}"


def test_every_recorded_result_is_quoted_and_says_how_it_was_made():
    quoted = {f.name for f in figures.check(REPO)}
    for path in sorted(figures.RESULTS.glob("*.json")):
        data = figures.load_results(path.stem)
        assert path.stem in quoted, f"{path.name}: recorded but quoted nowhere"
        assert {"command", "commit", "started_utc", "wall_s", "load_average", "cores"} <= set(data), path.name


@pytest.mark.parametrize("shown, key, value, ok", [
    ("0.45", "a", 0.4512, True), ("0.451", "a", 0.4512, True), ("0.43", "a", 0.4512, False),
    ("2,120", "a", 2119.6, True), ("−0.04", "a", -0.041, True), ("+0.06", "a", 0.064, True),
    ("97.2", "a *100", 0.9722, True), ("3", "a /60", 191.0, True), ("3", "a /60", 215.0, False),
])
def test_a_figure_is_read_at_the_decimals_it_shows(shown, key, value, ok):
    name, _, scale = key.partition(" ")
    doc = f"| x | **{shown}**<!--fig r {name}{' ' + scale if scale else ''}--> mrad | y |"
    (fig,) = figures.check_text(doc, "d.md", lambda n: {"output": {"a": value}})
    assert (fig.problem is None) == ok, fig
    assert fig.shown.lstrip("+") == shown.lstrip("+")


def test_a_wrong_missing_or_unmarked_source_is_named():
    text = ("seed 0: 0.77<!--fig r nights.0.rms--> then 0.50<!--fig r nights.1.rms-->\n"
            "7<!--fig r nights.9.rms--> 8<!--fig gone x--> <!--fig r nights.0.rms-->"
            " 191 s<!--fig r @wall_s-->")
    recorded = {"wall_s": 190.6, "output": {"nights": [{"rms": 0.771}, {"rms": 0.514}]}}

    def load(name):
        if name != "r":
            raise FileNotFoundError(name)
        return recorded

    found = figures.check_text(text, "d.md", load)
    problems = [f.problem for f in found]
    assert problems[0] is None and re.search(r"shows 0\.50, but r nights\.1\.rms is 0\.514", problems[1])
    assert "no '9'" in problems[2] and "no benchmarks/results/gone.json" in problems[3]
    assert "no number before the marker" in problems[4] and found[1].line == 1 and found[4].line == 2
    assert problems[5] is None and found[5].value == 190.6
    shown = "A figure is marked so: `0.45<!--fig r nights.0.rms-->`.\n```\n7<!--fig r x-->\n```\n"
    assert figures.check_text(shown, "d.md", load) == []
