"""Markdown helpers for the docs tests: headings' anchors (GitHub's rule), links, code blocks."""

from __future__ import annotations

import re
from pathlib import Path

FENCE = re.compile(r"^(?P<indent>[ \t]*)```[^\n]*\n(?P<body>.*?)^(?P=indent)```", re.S | re.M)


def anchors(text: str) -> set[str]:
    """GitHub's heading anchors: lower case, punctuation dropped, spaces to '-', repeats numbered."""
    seen: dict[str, int] = {}
    out = set()
    for line in strip_code(text).splitlines():
        m = re.match(r"#{1,6} (.*)", line)
        if not m:
            continue
        slug = re.sub(r"[^\w\- ]", "", m.group(1).strip().lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def strip_code(text: str) -> str:
    return FENCE.sub("", text)


def links(text: str) -> list[str]:
    return re.findall(r"\]\(([^)\s]+)\)", re.sub(r"`[^`\n]*`", "", strip_code(text)))


def code_blocks(text: str) -> list[str]:
    return [m.group("body") for m in FENCE.finditer(text)]


def table_cells(text: str) -> list[str]:
    cells = []
    for line in strip_code(text).splitlines():
        if line.startswith("|") and not re.match(r"\|\s*:?-{3}", line):
            cells += [c.strip() for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]
    return cells


def broken_links(path: Path) -> list[str]:
    """Relative links of one Markdown file whose file or heading anchor does not exist."""
    bad = []
    for link in links(path.read_text(encoding="utf-8")):
        if re.match(r"[a-z]+:", link):
            continue
        target, _, anchor = link.partition("#")
        file = (path.parent / target).resolve() if target else path
        if not file.exists():
            bad.append(f"{path.name}: {link}: no file {target}")
        elif anchor and file.suffix == ".md" and anchor not in anchors(file.read_text(encoding="utf-8")):
            bad.append(f"{path.name}: {link}: no heading #{anchor} in {file.name}")
    return bad
