"""The figures the README and the docs quote, each checked against the recorded output it comes
from (``benchmarks/results/NAME.json``, written by ``benchmarks/record.py``).

A figure is marked in the Markdown right after its number, by an HTML comment (invisible on the
rendered page):

    **0.45**<!--fig demo-seed0 daytime_error_mrad.rms--> mrad RMS
    about 3<!--fig make-demo @wall_s /60--> minutes

``NAME`` is the results file, ``KEY`` the dotted path into what the command printed (its
``output``; a list item by its index; a key may hold spaces, ``seeds.1.hu (paper).rate``) or,
after ``@``, into the recording itself (``@wall_s``, ``@load_average.0``), and an optional
``*F`` or ``/F`` scales the recorded value (``*100``: a rate as a percentage; ``/60``: seconds
as minutes). The figure is the last number before the marker in the same line and table
cell, after any earlier marker; a thousands separator ``,`` and the minus sign ``−`` are read.
It agrees when the recorded value rounds to it at the decimals it shows (0.4786 is "0.48" and
"0.479", not "0.47"). Markers in code (a code span or block) show the syntax and are skipped.

To add a figure: record its source once (``python benchmarks/record.py NAME -- COMMAND``),
commit the JSON, write the number in the doc and mark it. After a benchmark is recorded again,
``python benchmarks/figures.py`` lists every figure that no longer agrees with the value it
should read now (``--update`` writes those values in their place: read the diff, the sentences
around them may need a word too); ``tests/test_doc_figures.py`` fails on each of them.

    python benchmarks/figures.py [--update]
"""

from __future__ import annotations

import json
import re
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
MARKER = re.compile(r"<!--\s*fig\s+([a-z0-9][a-z0-9-]*)\s+(@?[^*/>]+?)(?:\s+([*/])\s*([0-9.]+))?\s*-->")
NUMBER = re.compile(r"(?<![\w.])[−-]?(?:\d{1,3}(?:,\d{3})+|\d+)(?:\.\d+)?(?![\d])")


@dataclass
class Figure:
    """One marked figure: where it is (``doc``, ``line``), the number as shown, its source
    (``name``, ``key``, scale) and the recorded value scaled (None when it cannot be read);
    ``problem`` says why it does not agree (None when it does)."""

    doc: str
    line: int
    shown: str | None
    name: str
    key: str
    scale: str
    value: float | None
    problem: str | None
    span: tuple[int, int] | None = None  # the number's columns in its line

    def __str__(self) -> str:
        where = f"{self.doc}:{self.line}"
        if self.problem is None:
            return f"{where}: {self.shown} = {self.name} {self.key}{self.scale} ({self.value:.6g})"
        return f"{where}: {self.problem}"


def docs(root: Path = ROOT) -> list[Path]:
    """The Markdown files whose figures are checked: the README and every page of docs/."""
    return [root / "README.md", *sorted((root / "docs").glob("*.md"))]


def lookup(data: dict, key: str):
    """The value at dotted ``key`` in a recording's ``output`` (after ``@``: in the recording
    itself); a list item by its index. KeyError naming the first part that is not there."""
    if key.startswith("@"):
        key = key[1:]
    else:
        data = data.get("output")
    for part in key.split("."):
        if isinstance(data, list) and part.isdigit() and int(part) < len(data):
            data = data[int(part)]
        elif isinstance(data, dict) and part in data:
            data = data[part]
        else:
            raise KeyError(part)
    return data


def agrees(shown: str, value: float) -> bool:
    """Whether ``value`` rounds to the number ``shown`` at the decimals it has."""
    text = shown.replace(",", "").replace("−", "-")
    decimals = len(text.split(".")[1]) if "." in text else 0
    return abs(value - float(text)) <= 0.5 * 10 ** -decimals + 1e-9


def check_text(text: str, doc: str, load) -> list[Figure]:
    """Every marked figure of Markdown ``text`` (from ``doc``), its source read by
    ``load(name)`` (the results file's data; FileNotFoundError when there is none)."""
    out = []
    fenced = False
    for number, line in enumerate(text.splitlines(), 1):
        if line.lstrip().startswith("```"):
            fenced = not fenced
        if fenced:
            continue  # a code block shows markers, it does not mark figures
        code = [m.span() for m in re.finditer(r"`[^`]*`", line)]
        start = 0
        for m in MARKER.finditer(line):
            if any(a < m.start() < b for a, b in code):
                continue  # the syntax shown in `code`, not a figure
            lo = max(start, line.rfind("|", 0, m.start()) + 1)
            start = m.end()
            found = list(NUMBER.finditer(line, lo, m.start()))
            shown = found[-1].group(0) if found else None
            name, key, op, factor = m.group(1), m.group(2), m.group(3) or "", m.group(4) or ""
            scale = f" {op}{factor}" if op else ""
            fig = Figure(doc, number, shown, name, key, scale, None, None,
                         found[-1].span() if found else None)
            try:
                raw = lookup(load(name), key)
            except FileNotFoundError:
                fig.problem = f"no benchmarks/results/{name}.json (record it: benchmarks/record.py)"
            except KeyError as exc:
                fig.problem = f"benchmarks/results/{name}.json has no {key!r} (no {exc.args[0]!r})"
            else:
                if not isinstance(raw, (int, float)) or isinstance(raw, bool):
                    fig.problem = f"{name} {key} is not a number: {raw!r}"
                else:
                    value = float(raw)
                    fig.value = value * float(factor) if op == "*" else value / float(factor) if op else value
            if fig.problem is None and shown is None:
                fig.problem = f"no number before the marker of {name} {key}"
            elif fig.problem is None and not agrees(shown, fig.value):
                fig.problem = (f"shows {shown}, but {name} {key}{scale} is {fig.value:.6g} "
                               f"(benchmarks/results/{name}.json, {load(name).get('started_utc', '?')})")
            out.append(fig)
    return out


def load_results(name: str) -> dict:
    return json.loads((RESULTS / f"{name}.json").read_text(encoding="utf-8"))


def check(root: Path = ROOT) -> list[Figure]:
    """Every marked figure of the README and docs/ against benchmarks/results/."""
    cache: dict[str, dict] = {}

    def load(name: str) -> dict:
        if name not in cache:
            cache[name] = load_results(name)
        return cache[name]

    return [f for doc in docs(root)
            for f in check_text(doc.read_text(encoding="utf-8"), str(doc.relative_to(root)), load)]


def shown_as(value: float, shown: str) -> str:
    """``value`` written as ``shown`` is: its decimals, thousands separator and minus sign."""
    decimals = len(shown.split(".")[1]) if "." in shown else 0
    text = f"{value:,.{decimals}f}" if "," in shown else f"{value:.{decimals}f}"
    return text.replace("-", "−") if "−" in shown or value < 0 and "-" not in shown else text


def update(root: Path, figures: list[Figure]) -> int:
    """Write the recorded value in place of every figure that disagrees with it (at the
    decimals it showed); returns how many. The sentences around them are not rewritten: read
    the diff."""
    done = 0
    for doc in {f.doc for f in figures}:
        path = root / doc
        lines = path.read_text(encoding="utf-8").split("\n")
        mine = [f for f in figures if f.doc == doc and f.problem and f.value is not None and f.span]
        for f in sorted(mine, key=lambda f: (f.line, -f.span[0])):
            a, b = f.span
            text = lines[f.line - 1]
            lines[f.line - 1] = text[:a] + shown_as(f.value, f.shown) + text[b:]
            done += 1
        if mine:
            path.write_text("\n".join(lines), encoding="utf-8")
    return done


def main(argv: list[str]) -> int:
    figures = check()
    if argv == ["--update"]:
        print(f"figures.py: {update(ROOT, figures)} figures rewritten with their recorded values; "
              "read the diff (the sentences around them are as they were)", file=sys.stderr)
        figures = check()
    elif argv:
        print("usage: python benchmarks/figures.py [--update]", file=sys.stderr)
        return 2
    for f in figures:
        print(f)
    bad = [f for f in figures if f.problem]
    print(f"{len(figures)} figures, {len(bad)} disagree", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
