"""What went wrong, in the morning report: the frames of the captures that gave no measurement
(a frame with no beam, a spot clipped at the view's edge — what the camera saw when it mattered
most) and the geometries flagged after failing on two nights (docs/nights.md).

Both are Markdown lines the night report's page renders; :func:`failed_captures` also gives
the campaign report its HTML.
"""

from __future__ import annotations

import html
from collections.abc import Callable
from pathlib import Path

from controller.storage.db import CampaignStore
from controller.storage.images import failed_frames

SHOWN = 40  # captures shown with their frame; the rest are counted


def failed_captures(store: CampaignStore, campaign_ids: list[int], out: Path,
                    thumbnail: Callable[[str, Path], bool], prefix: str = "") -> tuple[list[str], str]:
    """The section of the captures of ``campaign_ids`` that gave no measurement, each with a
    thumbnail of its HIGH frame (written under ``out/thumbs`` by ``thumbnail(frame, dest)``,
    :func:`controller.reports.campaign.write_thumbnail`), as Markdown lines and as HTML; nothing
    when there is none. ``prefix`` is left out of the campaign names shown."""
    frames = failed_frames(store, campaign_ids)
    if not frames:
        return [], ""
    rows = []
    for f in frames[:SHOWN]:
        rel = f"thumbs/nomeasure-{f['campaign_id']}-{f['heliostat']}.png"
        shot = f"![{f['heliostat']}]({rel})" if thumbnail(f["path"], out / rel) else "(frame missing)"
        rows.append([f["heliostat"], f["campaign"].removeprefix(prefix), f["status"].replace("_", " "),
                     f["state"] or "–", (f["cause"] or "").replace("|", "/"), shot])
    cols = ["heliostat", "campaign", "status", "in state", "why", "HIGH frame"]
    more = f" The first {SHOWN} of {len(frames)}." if len(frames) > SHOWN else ""
    intro = (f"{len(frames)} capture(s) put a beam on the target and gave no measurement: what the camera "
             f"saw.{more}")
    lines = ["", "## Captures that gave no measurement", "", intro, "", *_md_table(cols, rows)]
    e = html.escape
    cells = "".join("<tr>" + "".join(f"<td>{_img(c) or e(c)}</td>" for c in r) + "</tr>" for r in rows)
    page = (f"<h2>Captures that gave no measurement</h2><p>{e(intro)}</p><table><tr>"
            + "".join(f"<th>{e(c)}</th>" for c in cols) + f"</tr>{cells}</table>")
    return lines, page


def flagged_lines(flags: list[dict]) -> list[str]:
    """The section of the geometries flagged after failing on two nights (not planned again until
    cleared), as Markdown lines; nothing when there is none."""
    if not flags:
        return []
    cols = ["heliostat", "lamp", "target", "aim cell", "failed on", "last cause"]
    rows = [[g["heliostat"], g["lamp"], g["target"] or "every target",
             "every cell" if g["cell"] is None else f"{g['cell'][0]},{g['cell'][1]}", ", ".join(g["nights"]),
             (g["cause"] or "").replace("|", "/")] for g in flags]
    return ["", "## Flagged geometries", "",
            f"{len(flags)} geometr{'y' if len(flags) == 1 else 'ies'} failed on two nights: not planned "
            "again until cleared (`heliocal campaign flags --db DB --clear IDS`).", "",
            *_md_table(cols, rows)]


def _md_table(cols: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(cols) + " |", "|" + " --- |" * len(cols),
            *["| " + " | ".join(r) + " |" for r in rows]]


def _img(cell: str) -> str | None:
    if cell.startswith("![") and cell.endswith(")"):
        alt, src = cell[2:-1].split("](", 1)
        return f"<img src='{html.escape(src)}' alt='{html.escape(alt)}'>"
    return None
