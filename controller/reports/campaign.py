"""The morning report of a calibration campaign: Markdown + HTML with plots, from the database.

``write_report(store, out_dir, campaign_id=None)`` writes into ``out_dir``:

* ``report.md`` and ``report.html``: summary, per-heliostat table (status, iterations, matched
  error case, error before/after, target occupancy, fault cause) and, for a simulated plant,
  the confusion matrix of the matched error case against the injected truth;
* ``errors_hist.png``: pointing error before and after calibration (histogram, mrad);
* ``centroids.png``: every measured beam centroid on the target plane (m from the aim
  point, first measurement vs last), with the target outline;
* ``time_per_heliostat.png``: plant-clock time per heliostat (slew to standby, waiting for the
  target, on target);
* ``confusion.png`` (simulation only).

Errors in the table are the *measured* reflected-beam errors (centroid on the target); a
simulated campaign adds the simulated truth. Everything is written atomically.
"""

from __future__ import annotations

import html
import json
from pathlib import Path

import numpy as np

from controller.calibration.campaign import summarize
from controller.io.images import save_figure, write_atomic
from controller.storage.db import CampaignStore


def _fmt(v, nd: int = 3) -> str:
    return "–" if v is None else f"{v:.{nd}f}"


def _plots(store: CampaignStore, cid: int, runs, out: Path, simulated: bool) -> list[tuple[str, str]]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figs = []
    before = [r["error_before_mrad"] for r in runs if r["error_before_mrad"] is not None]
    after = [r["error_after_mrad"] for r in runs if r["error_after_mrad"] is not None]
    fig, ax = plt.subplots(figsize=(6, 3.6))
    hi = max(before + after + [1.0])
    bins = np.linspace(0, hi * 1.05, 25)
    ax.hist(before, bins=bins, alpha=0.6, label="before (first measurement)")
    ax.hist(after, bins=bins, alpha=0.8, label="after calibration")
    ax.set_xlabel("reflected-beam pointing error, mrad (measured)")
    ax.set_ylabel("heliostats")
    ax.legend()
    save_figure(fig, out / "errors_hist.png", dpi=110, bbox_inches="tight")
    figs.append(("Pointing error before / after", "errors_hist.png"))

    meas = store.measurements(campaign_id=cid)
    camp = store.campaign(cid)
    fig, ax = plt.subplots(figsize=(5.2, 5))
    if meas:
        aim = np.array([[m["aim_e"], m["aim_n"], m["aim_u"]] for m in meas])
        c = np.array([[m["centroid_e"] or 0, m["centroid_n"] or 0, m["centroid_u"] or 0] for m in meas])
        d = c - aim
        # The target plane's in-plane axes: horizontal (east-ish) and up.
        up = np.array([0.0, 0.0, 1.0])
        nrm = _target_normal(camp)
        h = np.cross(up, nrm)
        h = h / np.linalg.norm(h) if np.linalg.norm(h) > 1e-9 else np.array([1.0, 0.0, 0.0])
        v = np.cross(nrm, h)
        x, y = d @ h, d @ v
        last = {}
        for i, m in enumerate(meas):
            last[m["run_id"]] = i
        first = [i for i, m in enumerate(meas) if m["iteration"] == 1]
        fin = sorted(last.values())
        ax.scatter(x[first], y[first], s=18, label="first measurement")
        ax.scatter(x[fin], y[fin], s=18, marker="x", label="final")
    ax.axhline(0, lw=0.5, color="k")
    ax.axvline(0, lw=0.5, color="k")
    ax.set_aspect("equal")
    ax.set_xlabel("horizontal offset on the target, m (+ = right as seen from the field)")
    ax.set_ylabel("vertical offset, m (up = +)")
    ax.legend(fontsize=8)
    save_figure(fig, out / "centroids.png", dpi=110, bbox_inches="tight")
    figs.append(("Beam centroids on the target (relative to the aim point)", "centroids.png"))

    fig, ax = plt.subplots(figsize=(7, 3.6))
    ids = [r["heliostat_id"] for r in runs]
    prep = [_diff(r["at_standby_s"], r["start_s"]) for r in runs]
    wait = [_diff(r["on_target_s"], r["at_standby_s"]) for r in runs]
    occ = [_diff(r["off_target_s"], r["on_target_s"]) for r in runs]
    pos = np.arange(len(ids))
    ax.bar(pos, prep, label="slew to standby")
    ax.bar(pos, wait, bottom=prep, label="waiting at standby")
    ax.bar(pos, occ, bottom=np.add(prep, wait), label="on target (approach … parked)")
    ax.set_xticks(pos, ids, rotation=60, fontsize=8)
    ax.set_ylabel("plant time, s")
    ax.legend(fontsize=8)
    save_figure(fig, out / "time_per_heliostat.png", dpi=110, bbox_inches="tight")
    figs.append(("Time per heliostat (plant clock)", "time_per_heliostat.png"))
    return figs


def _diff(a, b) -> float:
    return float(a - b) if a is not None and b is not None else 0.0


def _target_normal(camp) -> np.ndarray:
    meta = json.loads(camp["meta_json"] or "{}")
    return np.asarray(meta.get("target_normal", (0.0, 1.0, 0.0)), float)


def _confusion(runs, out: Path) -> tuple[dict, str] | None:
    from controller.calibration.confusion import UNKNOWN, confusion

    pairs = [(r["truth_label"], r["matched_label"] or UNKNOWN) for r in runs
             if r["truth_label"] and r["iterations"] > 0]
    if not pairs:
        return None
    labels = sorted({t for t, _ in pairs} | {p for _, p in pairs if p != UNKNOWN})
    cm = confusion([t for t, _ in pairs], [p for _, p in pairs], labels)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4.5))
    ax.imshow(cm.matrix, cmap="Blues")
    ax.set_xticks(range(len(labels)), labels, rotation=45, ha="right", fontsize=8)
    ax.set_yticks(range(len(labels)), labels, fontsize=8)
    for i in range(len(labels)):
        for j in range(len(labels)):
            ax.text(j, i, int(cm.matrix[i, j]), ha="center", va="center", fontsize=8)
    ax.set_xlabel("matched case")
    ax.set_ylabel("injected truth")
    save_figure(fig, out / "confusion.png", dpi=110, bbox_inches="tight")
    unknown = {lab: int(u) for lab, u in zip(labels, cm.unknown, strict=True)}
    return {"labels": labels, "matrix": cm.matrix.tolist(), "unknown": unknown,
            "recognition_rate": 100.0 * cm.tp / len(pairs), "n": len(pairs)}, "confusion.png"


def write_report(store: CampaignStore, out_dir: str | Path, campaign_id: int | None = None) -> Path:
    """Write the report of ``campaign_id`` (default: the latest) into ``out_dir``; returns the
    path of ``report.md``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    camp = store.campaign(campaign_id)
    cid = int(camp["id"])
    runs = store.runs(cid)
    simulated = bool(camp["simulated"])
    s = summarize(store, cid, truth=False)
    st = summarize(store, cid, truth=True) if simulated else None
    meta = json.loads(camp["meta_json"] or "{}")
    figs = _plots(store, cid, runs, out, simulated)
    conf = _confusion(runs, out) if simulated else None

    cols = ["heliostat", "status", "iterations", "matched case", "error before mrad", "error after mrad"]
    if simulated:
        cols += ["true case", "true error before mrad", "true error after mrad"]
    cols += ["on target s", "fault"]
    rows = []
    for r in runs:
        row = [r["heliostat_id"], r["status"], str(r["iterations"]), r["matched_label"] or "–",
               _fmt(r["error_before_mrad"]), _fmt(r["error_after_mrad"])]
        if simulated:
            row += [r["truth_label"] or "–", _fmt(r["true_error_before_mrad"]),
                    _fmt(r["true_error_after_mrad"])]
        row += [_fmt(_diff(r["off_target_s"], r["on_target_s"]) if r["on_target_s"] else None, 1),
                (f"{r['fault_cause']} (in {r['fault_state']})" if r["fault_cause"] else "")]
        rows.append(row)

    lines = [f"# Morning report: campaign `{camp['name']}`", ""]
    lines += [f"- started {camp['started_utc']}, finished {camp['finished_utc'] or '–'}, "
              f"status **{camp['status']}**",
              f"- configuration `{camp['config_path']}` (sha256 {camp['config_sha256'][:12]}…), "
              f"light source `{camp['light_source']}`, target `{camp['target']}`",
              f"- heliostats {s['heliostats']}: calibrated **{s['calibrated']}**, failed or not converged "
              f"**{s['failed']}**, recorded {len(runs)}",
              f"- measured pointing error before: mean {_fmt(s['error_before_mrad']['mean'])} / max "
              f"{_fmt(s['error_before_mrad']['max'])} mrad; after: mean {_fmt(s['error_after_mrad']['mean'])}"
              f" / max {_fmt(s['error_after_mrad']['max'])} mrad",
              f"- iterations per heliostat: {_fmt(s['iterations_mean'], 2)}; mean target occupancy "
              f"{_fmt(s['target_occupancy_s_mean'], 1)} s; {_fmt(s['heliostats_per_hour'], 0)} heliostats "
              f"per hour on this target; pipelined speedup {_fmt(s['pipelined_speedup'], 2)}x (plant clock)"]
    if simulated and st is not None:
        lines += [f"- **simulated plant** (clock {meta.get('clock_speedup', '?')}x real time): true error "
                  f"before mean {_fmt(st['error_before_mrad']['mean'])} / max "
                  f"{_fmt(st['error_before_mrad']['max'])}"
                  f" mrad, after mean {_fmt(st['error_after_mrad']['mean'])} / max "
                  f"{_fmt(st['error_after_mrad']['max'])} mrad"]
        safety = meta.get("beam_safety_last_session")
        if safety:
            lines += [f"- beam safety (plant truth, last session): {safety['violations']} samples with two "
                      f"beams on the target out of {safety['samples']}"]
    lines += ["", "## Heliostats", "", "| " + " | ".join(cols) + " |", "|" + " --- |" * len(cols)]
    lines += ["| " + " | ".join(c.replace("|", "/") for c in row) + " |" for row in rows]
    for title, png in figs:
        lines += ["", f"## {title}", "", f"![{title}]({png})"]
    if conf is not None:
        c, png = conf
        lines += ["", "## Matched error case vs injected truth (simulation)", "",
                  "| true \\ matched | " + " | ".join(c["labels"]) + " | unknown |",
                  "|" + " --- |" * (len(c["labels"]) + 2)]
        for lab, row in zip(c["labels"], c["matrix"], strict=True):
            lines.append(f"| {lab} | " + " | ".join(str(v) for v in row) + f" | {c['unknown'][lab]} |")
        lines += ["", f"Recognition rate {c['recognition_rate']:.1f} % of {c['n']} heliostats "
                      "(first measurement; unknown counts as a miss).", "", f"![confusion]({png})"]
    md = "\n".join(lines) + "\n"
    write_atomic(out / "report.md", lambda t: t.write_text(md, encoding="utf-8"))
    write_atomic(out / "report.html", lambda t: t.write_text(_html(camp, lines, cols, rows, figs, conf),
                                                             encoding="utf-8"))
    return out / "report.md"


def _html(camp, lines, cols, rows, figs, conf) -> str:
    e = html.escape
    bullets = "".join(f"<li>{e(line[2:]).replace('**', '')}</li>" for line in lines if line.startswith("- "))
    table = ("<table><tr>" + "".join(f"<th>{e(c)}</th>" for c in cols) + "</tr>"
             + "".join("<tr>" + "".join(f"<td>{e(v)}</td>" for v in row) + "</tr>" for row in rows)
             + "</table>")
    imgs = "".join(f"<h2>{e(t)}</h2><img src='{e(p)}' alt='{e(t)}'>" for t, p in figs)
    conf_html = ""
    if conf is not None:
        c, png = conf
        conf_html = ("<h2>Matched error case vs injected truth (simulation)</h2>"
                     "<table><tr><th>true \\ matched</th>"
                     + "".join(f"<th>{e(lab)}</th>" for lab in c["labels"]) + "<th>unknown</th></tr>"
                     + "".join(f"<tr><th>{e(lab)}</th>" + "".join(f"<td>{v}</td>" for v in row)
                               + f"<td>{c['unknown'][lab]}</td></tr>"
                               for lab, row in zip(c["labels"], c["matrix"], strict=True))
                     + f"</table><p>Recognition rate {c['recognition_rate']:.1f} % of {c['n']}.</p>"
                     f"<img src='{e(png)}' alt='confusion matrix'>")
    style = ("body{font-family:sans-serif;max-width:1100px;margin:auto}table{border-collapse:collapse}"
             "td,th{border:1px solid #bbb;padding:3px 6px;font-size:13px}img{max-width:100%}")
    return (f"<!doctype html><html><head><meta charset='utf-8'>"
            f"<title>Morning report {e(camp['name'])}</title>"
            f"<style>{style}</style></head><body><h1>Morning report: campaign {e(camp['name'])}</h1>"
            f"<ul>{bullets}</ul><h2>Heliostats</h2>{table}{imgs}{conf_html}</body></html>\n")
