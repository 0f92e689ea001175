"""The morning report of a planned night: what the night measured, pass by pass, and where the
field's models stand — readable at any field size.

``write_night_report(store, out_dir, night)`` writes into ``out_dir``:

* ``report.md`` and ``report.html``: the night (index, name, status and why, lamps lit with
  their confirmation, geometries measured of those planned, the daytime error the models now
  predict — open loop, from their covariance — and, for a simulated plant, the true one), its
  passes grouped by lamp (lamp, target, measured / heliostats, status), the field map and
  distributions, the :data:`WORST` heliostats of the field by predicted daytime error with a
  thumbnail of their latest frame, the heliostats that had no measurable geometry
  tonight and why, the geometries flagged after failing on two nights, the captures that gave
  no measurement with their HIGH frame, and — for a field of at most :data:`TABLE_MAX`
  heliostats — every heliostat's row;
* ``passes.png``: measured and planned geometries per lamp and target (bars);
* ``field_map.png``: every heliostat at its position, named, coloured by predicted daytime RMS;
* ``distributions.png``: predicted daytime RMS and geometries measured per heliostat;
* ``trend.png`` (from the second night on): night by night, the predicted daytime RMS and the
  measured first-look error of the heliostats with the largest predicted error tonight (every
  heliostat of a small field), with the field's predicted RMS;
* ``thumbs/``: the worst heliostats' HIGH frames, scaled down;
* ``heliostats.csv``: every heliostat's row.

A pass measures each of its heliostats once; a heliostat measured is never counted as failed.
What each heliostat ended the night with is read from ``night_heliostats`` (schema v9); a
night recorded before it has no map, and its per-heliostat table comes from its runs.
"""

from __future__ import annotations

import html
import re
from pathlib import Path

from controller.calibration.records import NightRecord
from controller.io.images import pyplot, save_figure, write_atomic
from controller.reports.campaign import _inline, _write_csv, write_thumbnail
from controller.reports.failures import failed_captures, flagged_lines
from controller.reports.field_figures import distributions, field_map, thumbnails, trend
from controller.storage.db import CampaignStore
from controller.storage.nights import NightBook

WORST = 20  # heliostats shown with a thumbnail
TABLE_MAX = 200  # beyond this many heliostats the full table is in heliostats.csv only
UNMEASURABLE_SHOWN = 50


def _rms(d: dict | None) -> str:
    return "–" if not d or d.get("rms") is None else f"{d['rms']:.2f} mrad RMS, p95 {d['p95']:.2f}"


def _num(v, nd: int = 3) -> str:
    return "–" if v is None else f"{v:.{nd}f}"


def night_campaigns(store: CampaignStore, night: NightRecord):
    """The campaigns of ``night``: its passes (and its first calibration), oldest first."""
    return [c for c in store.campaigns() if c.name.startswith(night.name + "/")]


def write_night_report(store: CampaignStore, out_dir: str | Path, night: NightRecord) -> Path:
    """Write the report of planned night ``night`` into ``out_dir`` (module docstring); returns
    the path of ``report.md``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    s = night.summary
    rows, per_helio, bars = [], {}, {}
    for c in night_campaigns(store, night):
        runs = store.runs(c.id)
        done = sum(r.status in ("measured", "calibrated") for r in runs)
        rows.append([c.name.removeprefix(night.name + "/"), c.light_source, c.target,
                     f"{done}/{len(c.queue)}", c.status, c.cause or ""])
        key = f"{c.light_source} @ {c.target}"
        got, planned = bars.get(key, (0, 0))
        bars[key] = (got + done, planned + len(c.queue))
        for r in runs:
            h = per_helio.setdefault(r.heliostat_id, [0, 0, []])
            h[0 if r.status in ("measured", "calibrated") else 1] += 1
            if r.fault_cause:
                h[2].append(r.fault_cause)
    field = NightBook(store).heliostats(night.id)
    lamps = ", ".join(f"{x['lamp']} ({'confirmed by the panel' if x['confirmed'] else 'operator'})"
                      for x in s.get("lamps", [])) or "none"
    lost = s.get("unmeasurable", [])
    lines = [f"# Morning report: night {night.index}, `{night.name}`", "",
             f"- started {night.started_utc}, finished {night.finished_utc or '–'}, status **{night.status}**"
             + (f": {night.cause}" if night.cause else ""),
             f"- geometries measured **{s.get('measured', 0)}** of {s.get('planned', 0)} planned, for "
             f"{s.get('heliostats', len(per_helio))} heliostats; lamps lit: {lamps}",
             f"- daytime error the models now predict (open loop, sun path, from their covariance): "
             f"{_rms(s.get('daytime_error_predicted_mrad'))}"]
    truth = s.get("truth", {}).get("daytime_error_mrad")
    if truth:
        lines.append("- **simulated plant**: true daytime error (open loop, plant truth of this night) "
                     f"{_rms(truth)}")
    if s.get("first_calibrated"):
        lines.append("- measured at the calibration lamp first (no model yet): "
                     + ", ".join(s["first_calibrated"]))
    if lost:
        lines.append(f"- heliostats with no measurable geometry tonight: **{len(lost)}** (below)")
    pcols = ["pass", "lamp", "target", "measured", "status", "cause"]
    lines += ["", "## Passes", "", *_table(pcols, rows)]
    figs = [("Geometries per lamp and target", _bars(bars, out))] if bars else []
    if field:
        figs += [("The field: predicted daytime error", field_map(field, out)),
                 ("Distributions", distributions(field, out))]
        trend_png = trend(store, night.index, field, NightBook(store).nights(), out)
        if trend_png:
            figs.append(("Per-heliostat trend across nights", trend_png))
    for title, png in figs:
        lines += ["", f"## {title}", "", f"![{title}]({png})"]
    ids = [r["heliostat"] for r in field] if field else list(per_helio)
    models = store.latest_models(ids)
    hcols = ["heliostat", "predicted daytime RMS mrad", "planned tonight", "measured tonight",
             "not measured", "model measurements", "model residual mrad", "why not measured"]

    def row(hid: str, r: dict | None) -> list[str]:
        ok, bad, why = per_helio.get(hid, [0, 0, []])
        m = models.get(hid)
        r = r or {}
        reason = "; ".join(why[:2]) or (r.get("unmeasurable") or "")
        return [hid, _num(r.get("predicted_rms_mrad"), 2), str(r.get("planned", "–")), str(ok), str(bad),
                str(m.n_measurements) if m else "–", _num(m.residual_mrad if m else None), reason]

    hrows = [row(r["heliostat"], r) for r in field] if field else [row(h, None) for h in sorted(per_helio)]
    if field:
        lines += _worst(store, night, field, out, row)
    if lost:
        more = (f"The first {UNMEASURABLE_SHOWN} below; all in heliostats.csv."
                if len(lost) > UNMEASURABLE_SHOWN else "")
        lines += ["", "## No measurable geometry tonight", "",
                  f"{len(lost)} heliostat(s): the planner found no geometry whose 3σ spot stays in the "
                  f"camera's view (or none it can reach). {more}", "",
                  *_table(["heliostat", "predicted daytime RMS mrad", "why"],
                          [[u["heliostat"], _num(u.get("predicted_mrad"), 2), u["why"]]
                           for u in lost[:UNMEASURABLE_SHOWN]])]
    lines += flagged_lines(NightBook(store).flagged(ids))
    lines += failed_captures(store, [c.id for c in night_campaigns(store, night)], out, write_thumbnail,
                             night.name + "/")[0]
    if len(hrows) <= TABLE_MAX:
        lines += ["", "## Heliostats", "", *_table(hcols, hrows)]
    else:
        lines += ["", "## Heliostats", "", f"All {len(hrows)} heliostats: heliostats.csv."]
    md = "\n".join(lines) + "\n"
    write_atomic(out / "report.md", lambda t: t.write_text(md, encoding="utf-8"))
    page = _page(f"Morning report: night {night.index}, {night.name}", lines)
    write_atomic(out / "report.html", lambda t: t.write_text(page, encoding="utf-8"))
    write_atomic(out / "heliostats.csv", lambda t: _write_csv(t, hcols, hrows))
    return out / "report.md"


def _worst(store: CampaignStore, night: NightRecord, field: list[dict], out: Path, row) -> list[str]:
    """The :data:`WORST` heliostats by predicted daytime RMS, each with its latest frame."""
    worst = sorted((r for r in field if r["predicted_rms_mrad"] is not None),
                   key=lambda r: -r["predicted_rms_mrad"])[:WORST]
    thumbs = thumbnails(store, [r["heliostat"] for r in worst], out)
    cols = ["heliostat", "predicted daytime RMS mrad", "planned", "measured", "latest frame",
            "why not measured"]
    rows = [[r["heliostat"], _num(r["predicted_rms_mrad"], 2), str(r["planned"]), str(r["measured"]),
             f"![{r['heliostat']}]({thumbs[r['heliostat']]})" if r["heliostat"] in thumbs else "–",
             row(r["heliostat"], r)[-1]] for r in worst]
    return ["", f"## The {len(worst)} heliostats with the largest predicted daytime error", "",
            *_table(cols, rows)]


def _table(cols: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(cols) + " |", "|" + " --- |" * len(cols),
            *["| " + " | ".join(x.replace("|", "/") for x in r) + " |" for r in rows]]


def _bars(bars: dict[str, tuple[int, int]], out: Path) -> str:
    """Measured over planned geometries per lamp and target, each bar labelled with its count.
    Saved to the tight box of everything drawn, so no lamp or target name is cut."""
    from matplotlib.ticker import MaxNLocator

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 0.4 * len(bars) + 1.5))
    keys = list(bars)
    planned = [bars[k][1] for k in keys]
    ax.barh(keys, planned, color="#dee2e6", label="planned")
    ax.barh(keys, [bars[k][0] for k in keys], color="#2f9e44", label="measured")
    for y, k in enumerate(keys):
        ax.annotate(f"{bars[k][0]}/{bars[k][1]}", (planned[y], y), xytext=(4, 0), textcoords="offset points",
                    va="center", fontsize=8)
    ax.set_xlim(0, max(planned + [1]) * 1.15)  # room for the counts
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("geometries")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)  # beside the bars, not on them
    ax.invert_yaxis()
    save_figure(fig, out / "passes.png", dpi=110, bbox_inches="tight")
    return "passes.png"


STYLE = ("body{font-family:sans-serif;max-width:1100px;margin:auto}table{border-collapse:collapse}"
         "td,th{border:1px solid #bbb;padding:3px 6px;font-size:13px}img{max-width:100%}")


def _cell(text: str) -> str:
    """A table cell: an image (``![alt](src)``, a thumbnail) as <img>, else inline Markdown."""
    m = re.fullmatch(r"!\[(.*)\]\((.*)\)", text)
    if m:
        return f"<img src='{html.escape(m[2])}' alt='{html.escape(m[1])}'>"
    return _inline(text)


def _page(title: str, lines: list[str]) -> str:
    """The report's Markdown ``lines`` (headings, bullets, paragraphs, tables, images) as one
    HTML page."""
    body, table, bullets = [], [], []

    def flush() -> None:
        if bullets:
            body.append("<ul>" + "".join(f"<li>{_inline(b)}</li>" for b in bullets) + "</ul>")
            bullets.clear()
        if table:
            head, rows = table[0], table[2:]
            body.append("<table><tr>" + "".join(f"<th>{_inline(c)}</th>" for c in head) + "</tr>"
                        + "".join("<tr>" + "".join(f"<td>{_cell(c)}</td>" for c in r) + "</tr>"
                                  for r in rows)
                        + "</table>")
            table.clear()

    for line in lines[1:]:
        if not line.strip():
            flush()
            continue
        if line.startswith("|"):
            table.append([c.strip() for c in line.strip().strip("|").split("|")])
            continue
        if line.startswith("- "):
            bullets.append(line[2:])
            continue
        flush()
        if line.startswith("## "):
            body.append(f"<h2>{_inline(line[3:])}</h2>")
        elif m := re.match(r"!\[(.*)\]\((.*)\)", line):
            body.append(f"<img src='{html.escape(m[2])}' alt='{html.escape(m[1])}'>")
        else:
            body.append(f"<p>{_inline(line)}</p>")
    flush()
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{STYLE}</style></head><body><h1>{html.escape(title)}</h1>{''.join(body)}</body></html>\n")
