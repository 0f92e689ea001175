"""The morning report of a planned night: what the night measured, pass by pass, and where the
field's models stand.

``write_night_report(store, out_dir, night)`` writes into ``out_dir``:

* ``report.md`` and ``report.html``: the night (index, name, status and why, lamps lit with
  their confirmation, geometries measured of those planned, the daytime error the models now
  predict — open loop, from their covariance — and, for a simulated plant, the true one), its
  passes grouped by lamp (lamp, target, measured / heliostats, status) and each heliostat's
  geometries measured tonight with its latest model;
* ``passes.png``: measured and planned geometries per lamp and target (bars);
* ``heliostats.csv``: the per-heliostat table.

A pass measures each of its heliostats once; a heliostat measured is never counted as failed.
"""

from __future__ import annotations

import html
from pathlib import Path

from controller.calibration.records import NightRecord
from controller.io.images import pyplot, save_figure, write_atomic
from controller.reports.campaign import _inline, _write_csv
from controller.storage.db import CampaignStore


def _rms(d: dict | None) -> str:
    return "–" if not d or d.get("rms") is None else f"{d['rms']:.2f} mrad RMS, p95 {d['p95']:.2f}"


def night_campaigns(store: CampaignStore, night: NightRecord):
    """The campaigns of ``night``: its passes (and its first calibration), oldest first."""
    return [c for c in store.campaigns() if c.name.startswith(night.name + "/")]


def write_night_report(store: CampaignStore, out_dir: str | Path, night: NightRecord) -> Path:
    """Write the report of planned night ``night`` into ``out_dir`` (module docstring); returns
    the path of ``report.md``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    s = night.summary
    camps = night_campaigns(store, night)
    rows, per_helio, bars = [], {}, {}
    for c in camps:
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
    lamps = ", ".join(f"{x['lamp']} ({'confirmed by the panel' if x['confirmed'] else 'operator'})"
                      for x in s.get("lamps", [])) or "none"
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
    pcols = ["pass", "lamp", "target", "measured", "status", "cause"]
    lines += ["", "## Passes", "", "| " + " | ".join(pcols) + " |", "|" + " --- |" * len(pcols)]
    lines += ["| " + " | ".join(x.replace("|", "/") for x in row) + " |" for row in rows]
    figs = [("Geometries per lamp and target", _bars(bars, out))] if bars else []
    hcols = ["heliostat", "measured tonight", "not measured", "model measurements", "model residual mrad",
             "why not measured"]
    hrows = []
    for hid, (ok, bad, why) in sorted(per_helio.items()):
        m = store.latest_model(hid)
        hrows.append([hid, str(ok), str(bad), str(m.n_measurements) if m else "–",
                      f"{m.residual_mrad:.3f}" if m and m.residual_mrad is not None else "–",
                      "; ".join(why[:2])])
    lines += ["", "## Heliostats", "", "| " + " | ".join(hcols) + " |", "|" + " --- |" * len(hcols)]
    lines += ["| " + " | ".join(x.replace("|", "/") for x in row) + " |" for row in hrows]
    for title, png in figs:
        lines += ["", f"## {title}", "", f"![{title}]({png})"]
    md = "\n".join(lines) + "\n"
    write_atomic(out / "report.md", lambda t: t.write_text(md, encoding="utf-8"))
    page = _page(f"Morning report: night {night.index}, {night.name}", lines)
    write_atomic(out / "report.html", lambda t: t.write_text(page, encoding="utf-8"))
    write_atomic(out / "heliostats.csv", lambda t: _write_csv(t, hcols, hrows))
    return out / "report.md"


def _bars(bars: dict[str, tuple[int, int]], out: Path) -> str:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 0.4 * len(bars) + 1.5))
    keys = list(bars)
    ax.barh(keys, [bars[k][1] for k in keys], color="#dee2e6", label="planned")
    ax.barh(keys, [bars[k][0] for k in keys], color="#2f9e44", label="measured")
    ax.set_xlabel("geometries")
    ax.legend(loc="lower right")
    ax.invert_yaxis()
    save_figure(fig, out / "passes.png")
    return "passes.png"


STYLE = ("body{font-family:sans-serif;max-width:1100px;margin:auto}table{border-collapse:collapse}"
         "td,th{border:1px solid #bbb;padding:3px 6px;font-size:13px}img{max-width:100%}")


def _page(title: str, lines: list[str]) -> str:
    """The report's Markdown ``lines`` (headings, bullets, tables, images) as one HTML page."""
    import re

    body, table, bullets = [], [], []

    def flush() -> None:
        if bullets:
            body.append("<ul>" + "".join(f"<li>{_inline(b)}</li>" for b in bullets) + "</ul>")
            bullets.clear()
        if table:
            head, rows = table[0], table[2:]
            body.append("<table><tr>" + "".join(f"<th>{_inline(c)}</th>" for c in head) + "</tr>"
                        + "".join("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in r) + "</tr>"
                                  for r in rows)
                        + "</table>")
            table.clear()

    for line in lines[1:]:
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
    flush()
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{STYLE}</style></head><body><h1>{html.escape(title)}</h1>{''.join(body)}</body></html>\n")
