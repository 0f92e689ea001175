"""The report of first light on a new field (docs/commissioning.md, "First light on a new field"):
per heliostat of a campaign, whether its beam was found, the beam search's looks and plant time,
where its beam landed relative to where its model (the nominal one, for a new heliostat) aimed
it, and how it ended; two figures (where the beams were found, the search time per heliostat).

``first_light`` reads the store; ``write_first_light`` writes ``first-light.md``,
``first-light.json`` and ``first-light.png`` into a folder. Units: m in the target plane
(u along the camera view's width, v down its height), plant-clock s.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from controller.io.images import pyplot, save_figure, write_atomic
from controller.storage.db import open_existing
from controller.storage.searches import campaign_searches


def first_light(db: str | Path, campaign_id: int) -> dict:
    """``heliostats`` (one dict each: ``heliostat``, ``status``, ``found``, ``search_looks``,
    ``search_skipped``, ``search_s``, ``miss_u_m``, ``miss_v_m``, ``miss_m``, ``iterations``,
    ``cycle_s``) and ``totals`` (``heliostats``, ``found``, ``calibrated``, ``searched``,
    ``search_looks``, ``search_s``, ``search_s_mean``, ``cycle_s_mean``) of campaign
    ``campaign_id`` in the store ``db``."""
    with open_existing(db) as store:
        runs = store.runs(campaign_id)
        searches = campaign_searches(store, campaign_id)
    rows = []
    for r in runs:
        s = searches.get(r.heliostat_id)
        miss = s.miss_m if s is not None else None
        rows.append({
            "heliostat": r.heliostat_id, "status": r.status,
            "found": bool(s.found) if s is not None else r.iterations > 0,
            "search_looks": s.looks if s is not None else 0,
            "search_skipped": s.skipped if s is not None else 0,
            "search_s": round(s.seconds, 1) if s is not None else 0.0,
            "miss_u_m": None if miss is None else miss[0], "miss_v_m": None if miss is None else miss[1],
            "miss_m": None if miss is None else round(math.hypot(*miss), 2),
            "iterations": r.iterations, "cycle_s": round(r.end_s - r.start_s, 1)})
    n = len(rows)
    looks = sum(x["search_looks"] for x in rows)
    secs = sum(x["search_s"] for x in rows)
    totals = {"heliostats": n, "found": sum(x["found"] for x in rows),
              "calibrated": sum(x["status"] == "calibrated" for x in rows),
              "searched": sum(x["search_looks"] > 0 for x in rows), "search_looks": looks,
              "search_s": round(secs, 1), "search_s_mean": round(secs / n, 1) if n else None,
              "cycle_s_mean": round(sum(x["cycle_s"] for x in rows) / n, 1) if n else None}
    return {"campaign_id": campaign_id, "heliostats": rows, "totals": totals}


def write_first_light(report: dict, folder: str | Path) -> Path:
    """Write the report into ``folder``; returns the Markdown file's path."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    rows, t = report["heliostats"], report["totals"]
    _figure(rows, out / "first-light.png")
    lines = ["# First light", "",
             f"{t['found']} of {t['heliostats']} beams found, {t['calibrated']} calibrated; the search "
             f"looked {t['search_looks']} times for {t['searched']} heliostats, {t['search_s']:.0f} s in "
             f"all (mean {t['search_s_mean']} s per heliostat; a cycle took {t['cycle_s_mean']} s on "
             "average).", "",
             "Miss: where the beam landed at the pose its model aimed it (m from the aim point, u across "
             "the view, v down it).", "",
             "| heliostat | status | found | search looks | refused | search s | miss u m | miss v m "
             "| miss m | iterations | cycle s |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for x in rows:
        cells = [x["heliostat"], x["status"], "yes" if x["found"] else "no", x["search_looks"],
                 x["search_skipped"], x["search_s"], x["miss_u_m"], x["miss_v_m"], x["miss_m"],
                 x["iterations"], x["cycle_s"]]
        lines.append("| " + " | ".join("–" if c is None else str(c) for c in cells) + " |")
    lines += ["", "![first light](first-light.png)", ""]
    md = out / "first-light.md"
    text = json.dumps(report, indent=1)
    write_atomic(out / "first-light.json", lambda p: p.write_text(text, encoding="utf-8"))
    write_atomic(md, lambda p: p.write_text("\n".join(lines), encoding="utf-8"))
    return md


def _figure(rows: list[dict], path: Path) -> None:
    """Left: each found beam's miss in the target plane; right: search seconds per heliostat."""
    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.5))
    found = [x for x in rows if x["miss_u_m"] is not None]
    a.scatter([x["miss_u_m"] for x in found], [x["miss_v_m"] for x in found], c="tab:blue")
    for x in found:
        a.annotate(x["heliostat"], (x["miss_u_m"], x["miss_v_m"]), fontsize=7)
    a.axhline(0, color="grey", lw=0.5)
    a.axvline(0, color="grey", lw=0.5)
    a.invert_yaxis()  # v runs down the view, as in the camera's image
    a.set(xlabel="u, m (across the view)", ylabel="v, m (down the view)", aspect="equal",
          title="where the nominal aim put each beam")
    ids = [x["heliostat"] for x in rows]
    b.bar(ids, [x["search_s"] for x in rows],
          color=["tab:green" if x["found"] else "tab:red" for x in rows])
    b.set(ylabel="search, plant s", title="beam search per heliostat (red: not found)")
    b.tick_params(axis="x", labelrotation=90)
    save_figure(fig, path, bbox_inches="tight")
