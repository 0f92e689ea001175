"""The morning report of a calibration campaign: Markdown + HTML with plots, from the database.

``write_report(store, out_dir, campaign_id=None)`` writes into ``out_dir``:

* ``report.md`` and ``report.html``: summary, per-heliostat table (status, iterations, matched
  error case, error before/after, target occupancy, fault cause) and, when a reference
  truth is given (a simulated plant's), the confusion matrix of the matched error case against it;
* ``errors_hist.png``: pointing error before and after calibration (histogram, mrad);
* ``centroids.png``: every measured beam centroid on the target plane (m from the aim
  point, first measurement vs last), with the target outline;
* ``time_per_heliostat.png``: plant-clock time per heliostat (slew to standby, waiting for the
  target, on target);
* ``trend.png`` (with earlier campaigns in the database): each heliostat's error after
  calibration, campaign by campaign;
* ``confusion.png`` (with a reference truth only);
* ``heliostats.csv``: the per-heliostat table for a spreadsheet;
* ``thumbs/``: the first and last measurement's HIGH frame of each heliostat, linked to the
  stored pair.

Errors in the table are the *measured* reflected-beam errors (centroid on the target); a
reference truth adds its errors. Everything is written atomically.
"""

from __future__ import annotations

import html
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from controller.calibration.records import CampaignRecord, RunRecord
from controller.errors import InputError
from controller.io.images import pyplot, read_image, save_figure, write_atomic
from controller.reports.confusion_plot import plot_confusion
from controller.reports.failures import failed_captures
from controller.reports.model_section import model_section
from controller.reports.summary import ReferenceTruth, summarize
from controller.storage.db import CampaignStore


def _fmt(v, nd: int = 3) -> str:
    return "–" if v is None else f"{v:.{nd}f}"


def _plots(store: CampaignStore, camp: CampaignRecord, runs: list[RunRecord],
           out: Path) -> list[tuple[str, str]]:
    plt = pyplot()

    figs = []
    before = [r.error_before_mrad for r in runs if r.error_before_mrad is not None]
    after = [r.error_after_mrad for r in runs if r.error_after_mrad is not None]
    fig, ax = plt.subplots(figsize=(6, 3.6))
    hi = max(before + after + [1.0])
    bins = np.linspace(0, hi * 1.05, 25)
    ax.hist(before, bins=bins, alpha=0.6, label="before (first measurement)")
    ax.hist(after, bins=bins, alpha=0.8, label="after calibration")
    ax.set_xlabel("reflected-beam pointing error, mrad (measured)")
    ax.set_ylabel("heliostats")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    save_figure(fig, out / "errors_hist.png", dpi=110, bbox_inches="tight")
    figs.append(("Pointing error before / after", "errors_hist.png"))

    meas = store.measurements(campaign_id=camp.id)
    fig, ax = plt.subplots(figsize=(5.2, 5))
    if meas:
        aim = np.array([m.aim_enu for m in meas])
        c = np.array([m.centroid_enu or (0.0, 0.0, 0.0) for m in meas])
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
            last[m.run_id] = i
        first = [i for i, m in enumerate(meas) if m.iteration == 1]
        fin = sorted(last.values())
        ax.scatter(x[first], y[first], s=18, label="first measurement")
        ax.scatter(x[fin], y[fin], s=18, marker="x", label="final")
        ax.legend(fontsize=8)
    ax.axhline(0, lw=0.5, color="k")
    ax.axvline(0, lw=0.5, color="k")
    ax.set_aspect("equal")
    ax.set_xlabel("horizontal offset on the target, m (+ = right as seen from the field)")
    ax.set_ylabel("vertical offset, m (up = +)")
    save_figure(fig, out / "centroids.png", dpi=110, bbox_inches="tight")
    figs.append(("Beam centroids on the target (relative to the aim point)", "centroids.png"))

    fig, ax = plt.subplots(figsize=(7, 3.6))
    ids = [r.heliostat_id for r in runs]
    prep = [_diff(r.at_standby_s, r.start_s) for r in runs]
    wait = [_diff(r.on_target_s, r.at_standby_s) for r in runs]
    occ = [_diff(r.off_target_s, r.on_target_s) for r in runs]
    pos = np.arange(len(ids))
    ax.bar(pos, prep, label="slew to standby")
    ax.bar(pos, wait, bottom=prep, label="waiting at standby")
    ax.bar(pos, occ, bottom=np.add(prep, wait), label="on target (approach … parked)")
    ax.set_xticks(pos, ids, rotation=60, fontsize=8)
    ax.set_ylabel("plant time, s")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))  # beside the bars, not on them
    save_figure(fig, out / "time_per_heliostat.png", dpi=110, bbox_inches="tight")
    figs.append(("Time per heliostat (plant clock)", "time_per_heliostat.png"))
    return figs


def _trend(store: CampaignStore, camp: CampaignRecord, out: Path) -> tuple[str, str] | None:
    """Each heliostat's measured error after calibration, night by night, over this campaign and
    the earlier ones of the database (None with fewer than two campaigns)."""
    nights = [c for c in store.campaigns() if c.id <= camp.id]
    if len(nights) < 2:
        return None
    plt = pyplot()

    series: dict[str, list[tuple[int, float]]] = {}
    for i, c in enumerate(nights):
        for r in store.runs(c.id):
            if r.error_after_mrad is not None:
                series.setdefault(r.heliostat_id, []).append((i, r.error_after_mrad))
    fig, ax = plt.subplots(figsize=(7, 3.6))
    for hid, pts in sorted(series.items()):
        ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", lw=1, label=hid)
    ax.set_xticks(range(len(nights)), [c.name for c in nights], rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("error after calibration, mrad (measured)")
    if len(series) <= 20:  # a legend of a whole field says nothing
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), ncol=1 + len(series) // 12)
    save_figure(fig, out / "trend.png", dpi=110, bbox_inches="tight")
    return ("Per-heliostat trend across campaigns", "trend.png")


def _diff(a, b) -> float:
    return float(a - b) if a is not None and b is not None else 0.0


def _target_normal(camp: CampaignRecord) -> np.ndarray:
    return np.asarray(camp.meta.get("target_normal", (0.0, 1.0, 0.0)), float)


def _confusion(runs: list[RunRecord], truth: Mapping[str, ReferenceTruth],
               out: Path) -> tuple[dict, str] | None:
    from controller.recognition.confusion import UNKNOWN, confusion

    pairs = [(truth[r.heliostat_id].label, r.matched_label or UNKNOWN) for r in runs
             if r.heliostat_id in truth and truth[r.heliostat_id].label and r.iterations > 0]
    if not pairs:
        return None
    labels = sorted({t for t, _ in pairs} | {p for _, p in pairs if p != UNKNOWN})
    cm = confusion([t for t, _ in pairs], [p for _, p in pairs], labels)
    rate = 100.0 * cm.tp / len(pairs)
    plot_confusion(cm.matrix, cm.unknown, labels, out / "confusion.png",
                   title=f"matched case vs injected truth: {rate:.1f} % of {len(pairs)}",
                   xlabel="matched case (first measurement)", ylabel="injected truth")
    unknown = {lab: int(u) for lab, u in zip(labels, cm.unknown, strict=True)}
    return {"labels": labels, "matrix": cm.matrix.tolist(), "unknown": unknown,
            "recognition_rate": rate, "n": len(pairs)}, "confusion.png"


def write_report(store: CampaignStore, out_dir: str | Path, campaign_id: int | None = None, *,
                 truth: Mapping[str, ReferenceTruth] | None = None,
                 accept_field_change: bool = False) -> Path:
    """Write the report of ``campaign_id`` (default: the latest) into ``out_dir``; returns the
    path of ``report.md``. ``truth`` (heliostat id -> :class:`ReferenceTruth`, e.g. a simulated
    plant's) adds the reference's case and errors and the confusion matrix against it.
    ``accept_field_change``: predict with the models although the campaign's configuration file
    now describes another field (:func:`controller.storage.field_prints.check_field`)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    camp = store.campaign(campaign_id)
    cid = camp.id
    runs = store.runs(cid)
    simulated = bool(truth)
    s = summarize(store, cid)
    st = summarize(store, cid, truth=truth) if truth else None
    meta = camp.meta
    # Empty plots say nothing: with no recorded run the report says so in words instead.
    figs = _plots(store, camp, runs, out) if runs else []
    trend = _trend(store, camp, out)
    if trend:
        figs.append(trend)
    conf = _confusion(runs, truth, out) if truth else None

    cols = ["heliostat", "status", "iterations", "matched case", "error before mrad", "error after mrad"]
    if simulated:
        cols += ["true case", "true error before mrad", "true error after mrad"]
    cols += ["on target s", "fault"]
    rows = []
    for r in runs:
        row = [r.heliostat_id, r.status, str(r.iterations), r.matched_label or "–",
               _fmt(r.error_before_mrad), _fmt(r.error_after_mrad)]
        if truth:
            t = truth.get(r.heliostat_id, ReferenceTruth(None, None, None))
            row += [t.label or "–", _fmt(t.error_before_mrad), _fmt(t.error_after_mrad)]
        row += [_fmt(r.target_occupancy_s, 1),
                (f"{r.fault_cause} (in {r.fault_state})" if r.fault_cause else "")]
        rows.append(row)

    lines = [f"# Morning report: campaign `{camp.name}`", ""]
    lines += [f"- started {camp.started_utc}, finished {camp.finished_utc or '–'}, status **{camp.status}**"
              + (f": {camp.cause}" if camp.cause else ""),
              f"- configuration `{camp.config_path}` (sha256 {camp.config_sha256[:12]}…), "
              f"light source `{camp.light_source}`, target `{camp.target}`",
              f"- heliostats {s['heliostats']}: "
              + (f"measured **{s['measured']}** (a planned night's pass), " if s["measured"] else "")
              + f"calibrated **{s['calibrated']}**, failed or not converged **{s['failed']}**, "
              f"recorded {len(runs)}",
              f"- measured pointing error before: mean {_fmt(s['error_before_mrad']['mean'])} / max "
              f"{_fmt(s['error_before_mrad']['max'])} mrad; after: mean {_fmt(s['error_after_mrad']['mean'])}"
              f" / max {_fmt(s['error_after_mrad']['max'])} mrad",
              f"- iterations per heliostat: {_fmt(s['iterations_mean'], 2)}; mean target occupancy "
              f"{_fmt(s['target_occupancy_s_mean'], 1)} s; {_fmt(s['heliostats_per_hour'], 0)} calibrated "
              f"heliostats per hour on this target; pipelined speedup {_fmt(s['pipelined_speedup'], 2)}x "
              "(plant clock)"]
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
    if not runs:
        lines += ["- no heliostat was recorded in this campaign, so there is nothing to plot"]
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
    model_lines, model_figs = model_section(store, camp, out, accept_field_change) if runs else ([], [])
    lines += model_lines
    for title, png in model_figs:
        lines += ["", f"### {title}", "", f"![{title}]({png})"]
    thumbs = _thumbnails(store, camp, runs, out)
    if thumbs:
        lines += ["", "## Beam before / after (first and last measurement, HIGH sensor)", ""]
        lines += [f"- {hid}: " + " → ".join(f"[![{k}]({t})]({src})" for k, t, src in pics)
                  for hid, pics in thumbs.items()]
    failed, failed_html = failed_captures(store, [cid], out, write_thumbnail)  # what the camera saw
    lines += failed
    md = "\n".join(lines) + "\n"
    write_atomic(out / "report.md", lambda t: t.write_text(md, encoding="utf-8"))
    page = _html(camp, lines, cols, rows, figs + model_figs, conf, thumbs,
                 _table_html(model_lines) + failed_html)
    write_atomic(out / "report.html", lambda t: t.write_text(page, encoding="utf-8"))
    write_atomic(out / "heliostats.csv", lambda t: _write_csv(t, cols, rows))
    return out / "report.md"


def _write_csv(path: Path, cols: list[str], rows: list[list[str]]) -> None:
    """The per-heliostat table as CSV (spreadsheet-friendly: plain numbers, '' for none)."""
    import csv

    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(cols)
        w.writerows([["" if v == "–" else v for v in row] for row in rows])


THUMB_PX = 160


def _thumbnails(store: CampaignStore, camp: CampaignRecord, runs: list[RunRecord],
                out: Path) -> dict[str, list[tuple[str, str, str]]]:
    """Per heliostat: (label, thumbnail path relative to ``out``, stored image) of its first
    and last measurement's HIGH frame, scaled to at most ``THUMB_PX`` wide. Frames no longer on
    disk are left out."""

    by_run: dict[int, list] = {}
    for m in store.measurements(campaign_id=camp.id):
        by_run.setdefault(m.run_id, []).append(m)
    thumbs: dict[str, list[tuple[str, str, str]]] = {}
    for r in runs:
        ms = by_run.get(r.id, [])
        for label, m in (("first", ms[0]), ("last", ms[-1])) if ms else ():
            high = next((im for im in store.images(m.id) if im.kind == "high"), None)
            rel = f"thumbs/{r.heliostat_id}-{label}.png"
            if high is not None and write_thumbnail(high.path, out / rel):
                thumbs.setdefault(r.heliostat_id, []).append((label, rel, Path(high.path).resolve().as_uri()))
    return thumbs


def write_thumbnail(image: str | Path, dest: Path) -> bool:
    """Write ``image`` scaled to at most ``THUMB_PX`` wide to ``dest`` (atomically); False when
    the stored frame is gone or no longer an image (the bounded reader refuses it)."""
    import cv2

    try:
        img = read_image(image)
    except InputError:
        return False
    scale = min(1.0, THUMB_PX / img.shape[1])
    small = cv2.resize(img, (max(1, int(img.shape[1] * scale)), max(1, int(img.shape[0] * scale))),
                       interpolation=cv2.INTER_AREA)

    def w(t: Path) -> None:
        if not cv2.imwrite(str(t), small):
            raise OSError(f"could not write {t}")
    write_atomic(dest, w)
    return True


def _inline(text: str) -> str:
    """Markdown's inline marks as HTML: escaped text, **bold** and `code`."""
    import re

    t = html.escape(text)
    t = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", t)
    return re.sub(r"`(.+?)`", r"<code>\1</code>", t)


def _table_html(lines: list[str]) -> str:
    """The Markdown table among ``lines`` (header, rule, rows) as an HTML table."""
    cells = [[c.strip() for c in line.strip().strip("|").split("|")]
             for line in lines if line.startswith("|")]
    if len(cells) < 2:
        return ""
    head, body = cells[0], cells[2:]
    return ("<h2>Tracking model and daytime pointing</h2><table><tr>"
            + "".join(f"<th>{_inline(c)}</th>" for c in head) + "</tr>"
            + "".join("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in row) + "</tr>" for row in body)
            + "</table>")


def _html(camp, lines, cols, rows, figs, conf, thumbs, model_table: str = "") -> str:
    e = html.escape
    bullets = "".join(f"<li>{_inline(line[2:])}</li>" for line in lines
                      if line.startswith("- ") and "![" not in line)
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
    if thumbs:
        conf_html += ("<h2>Beam before / after (first and last measurement, HIGH sensor)</h2><table>"
                      + "".join(f"<tr><th>{e(hid)}</th>" + "".join(
                          f"<td><a href='{e(src)}'><img src='{e(t)}' alt='{e(hid)} {k}'></a><br>{k}</td>"
                          for k, t, src in pics) + "</tr>" for hid, pics in thumbs.items()) + "</table>")
    style = ("body{font-family:sans-serif;max-width:1100px;margin:auto}table{border-collapse:collapse}"
             "td,th{border:1px solid #bbb;padding:3px 6px;font-size:13px}img{max-width:100%}")
    return (f"<!doctype html><html><head><meta charset='utf-8'>"
            f"<title>Morning report {e(camp.name)}</title>"
            f"<style>{style}</style></head><body><h1>Morning report: campaign {e(camp.name)}</h1>"
            f"<ul>{bullets}</ul><h2>Heliostats</h2>{table}{model_table}{imgs}{conf_html}</body></html>\n")
