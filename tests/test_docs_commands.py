"""Every `heliocal …` command shown in a code block of README.md and docs/*.md runs (issue 32).

A concrete example runs as written, in document order, in a sandbox folder per page that holds
`docs/`, `configs/` and `tests/data` of the repository, and `demo/` and `plant/`: one small demo
run (2 heliostats, the calibration night and one planned night) made once per session. It must
exit 0. A synopsis (options in brackets, alternatives, placeholders such as `DB` or `IMAGE`) is
checked against the command's `--help`: every option it shows must exist. Commands that need a
real device are listed in NOT_HERE with the reason. Also: README size and table cells, and
every relative link and anchor of the docs.
"""

from __future__ import annotations

import contextlib
import fcntl
import re
import shutil
import sqlite3
import subprocess
import sys
from functools import cache
from pathlib import Path

import pytest

from tests.docs_markdown import broken_links, code_blocks, table_cells
from tests.test_rehearsal import REHEARSAL

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]

# Commands shown as written that cannot run on this machine, with the reason.
NOT_HERE = {
    "heliocal lamps --config plant.yaml status": "a real field's lamp panel (plant.yaml's lamps: section)",
    "heliocal lamps --config plant.yaml on lamp-west": "a real field's lamp panel",
    "heliocal lamps --config plant.yaml all-off": "a real field's lamp panel",
    "heliocal capture --camera file --manifest pairs.yaml --config plant.yaml --out pair/":
        "recorded frame pairs of a real field (pairs.yaml)",
    "heliocal reprocess --db /plant/campaign.db --out /plant/reprocessed.db --scheduler tcp://10.0.0.5:8786":
        "a Dask scheduler on another machine",
    "heliocal commission --heliostat H05 --simulate --aim --capture a.png --store-reference rocking "
    "--library lib.yaml --verify --park --json":
        "run, and its printed figures checked, by tests/test_docs_examples.py",
    "heliocal demo --heliostats 2 --nights 1 --out demo":
        "the demo run this test's fixture makes (demo/ of the sandbox)",
    **dict.fromkeys(REHEARSAL.values(), "the rehearsal: serves until Ctrl-C, or needs it serving; "
                                        "tests/test_rehearsal.py runs these as written"),
}
PLACEHOLDER = re.compile(r"(?!H\d+$)[A-Z][A-Z0-9_]*([.:][A-Za-z0-9_.]+)?")


def shown_commands(page: Path) -> list[str]:
    """The `heliocal …` lines of the page's code blocks; continuations joined, comments and
    prompts dropped; printed output (`heliocal x: error: …`) left out."""
    out = []
    for block in code_blocks(page.read_text(encoding="utf-8")):
        for line in re.sub(r"\\\n\s*", " ", block).splitlines():
            line = re.sub(r"^\s*\$\s*", "", line).strip()
            line = re.sub(r"\s+#\s.*$", "", line)
            if line.startswith("heliocal ") and not re.match(r"heliocal( [\w-]+)*: ", line):
                out.append(" ".join(line.split()))
    return out


def is_synopsis(cmd: str) -> bool:
    return any(c in cmd for c in "[|…(") or "..." in cmd or any(
        PLACEHOLDER.fullmatch(tok) for tok in re.split(r"[\s=]", cmd)[1:])


@cache
def _help(words: tuple[str, ...]) -> str:
    r = subprocess.run([sys.executable, "-m", "controller.cli", *words, "--help"], capture_output=True,
                       text=True, timeout=120, cwd=REPO)
    assert r.returncode == 0, f"heliocal {' '.join(words)} --help: {r.stderr}"
    return r.stdout


def check_synopsis(cmd: str) -> list[str]:
    words = []
    for tok in cmd.split()[1:]:
        if not re.fullmatch(r"[a-z][a-z-]*", tok):
            break
        words.append(tok)
    while words:  # "heliocal lamps status" → lamps takes status as an argument
        try:
            text = _help(tuple(words))
            break
        except AssertionError:
            words.pop()
    else:
        return [f"{cmd}: no such command"]
    for sub in set(cmd.split()[len(words) + 1:]):  # a sub-command after the options: drive … status
        if re.fullmatch(r"[a-z][a-z-]*", sub) and re.search(rf"^\s+{sub}\s", text, re.M):
            text += _help((*words, sub))
    return [f"{cmd}: {opt} is not an option of heliocal {' '.join(words)}"
            for opt in re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", cmd) if opt not in text]


@pytest.fixture(scope="session")
def demo_run(tmp_path_factory, worker_id) -> Path:
    """The demo run, made once for the whole session: under xdist in the folder both workers'
    temporary folders share, the first to get there makes it (20 s) while the other waits on the
    lock; the pages only copy it."""
    root = tmp_path_factory.getbasetemp()
    root = root.parent if worker_id != "master" else root
    out, done = root / "docs-demo" / "demo", root / "docs-demo" / "made"
    with open(root / "docs-demo.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if done.is_file():
            return out
        shutil.rmtree(out.parent, ignore_errors=True)  # a worker's run that failed before it was made
        out.parent.mkdir()
        cmd = [sys.executable, "-m", "controller.cli", "demo", "--heliostats", "2", "--nights", "1",
               "--out", str(out)]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=out.parent)
        # closed here: left to the garbage collector, its close (which removes the -wal file) could
        # fall inside a copytree of the folder below
        with contextlib.closing(sqlite3.connect(out / "campaign.db")) as c:  # exits with its worst night
            partial = c.execute("SELECT COUNT(*) FROM nights WHERE status='partial'").fetchone()[0] > 0
        assert r.returncode == (3 if partial else 0), r.stderr[-2000:]
        done.touch()
    return out


def _sandbox(root: Path, demo: Path) -> Path:
    root.mkdir()
    for name in ("docs", "configs"):
        (root / name).symlink_to(REPO / name)
    (root / "tests" / "data").parent.mkdir()
    (root / "tests" / "data").symlink_to(REPO / "tests" / "data")
    for name in ("demo", "plant"):
        shutil.copytree(demo, root / name, ignore=shutil.ignore_patterns("images", "errorset", "*.lock"))
    return root


def test_every_page_shows_commands_the_test_can_tell_apart():
    every = [c for p in PAGES for c in shown_commands(p)]
    assert len(every) > 40
    assert set(NOT_HERE) <= set(every), set(NOT_HERE) - set(every)


@pytest.mark.parametrize("page", [p for p in PAGES if shown_commands(p)], ids=lambda p: p.name)
def test_every_shown_command_runs(page, demo_run, tmp_path):
    box = _sandbox(tmp_path / "box", demo_run)
    problems = []
    for cmd in shown_commands(page):
        if cmd in NOT_HERE:
            continue
        if is_synopsis(cmd):
            problems += check_synopsis(cmd)
            continue
        r = subprocess.run([sys.executable, "-m", "controller.cli", *cmd.split()[1:]], capture_output=True,
                           text=True, timeout=600, cwd=box)
        if r.returncode != 0:
            problems.append(f"{cmd}: exit {r.returncode}: {r.stderr.strip()[-400:]}")
    assert not problems, f"{page.name}:\n" + "\n".join(problems)


def test_readme_is_short_and_its_table_cells_too():
    # As a reader sees it: without the HTML comments that mark a figure's source (test_doc_figures).
    text = re.sub(r"<!--.*?-->", "", (REPO / "README.md").read_text(encoding="utf-8"))
    assert len(text) <= 9000, f"README.md: {len(text)} characters (at most 9,000)"
    long = [c[:60] for c in table_cells(text) if len(c) > 300]
    assert not long, f"README.md: table cells over 300 characters: {long}"
    assert table_cells(text), "the README's tables were not found"


def test_the_first_real_night_is_two_clicks_from_the_readme():
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    start = (REPO / "docs" / "getting-started.md").read_text(encoding="utf-8")
    assert "](docs/getting-started.md)" in readme
    assert "](nights.md#first-night-on-a-real-field-step-by-step)" in start
    assert "## First night on a real field, step by step" in (REPO / "docs" / "nights.md").read_text()


@pytest.mark.parametrize("page", [*PAGES, REPO / "firmware_proto" / "PROTOCOL.md"], ids=lambda p: p.name)
def test_relative_links_and_anchors_resolve(page):
    assert not broken_links(page)
