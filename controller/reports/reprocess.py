"""The diff report of an archive reprocessing: old vs new, per heliostat and for the field
(docs/reprocess.md).

Written into a folder beside the new database:

* ``reprocess.md``: the field summary, the heliostats whose model changed, the largest
  centroid shifts, and every pair that could not be re-analysed with its reason;
* ``heliostats.csv``: per heliostat its pairs by outcome, centroid shift (mm, new − old
  centroid on the target), model refit/changed, the terms that moved by more than their σ,
  new residual, and the predicted daytime error (mrad) of the old and the new model;
* ``models.csv``: per heliostat and term the old value, the new value, the new 1-σ and the move
  in σ;
* ``pairs.csv``: every pair not ``ok``, with its reason;
* ``reprocess.png``: the centroid shifts (histogram) and the predicted daytime error old vs new.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from controller.io.images import pyplot, save_figure, write_atomic
from controller.storage.reprocess.db import ReprocessDb

STATUSES = ("ok", "no_beam", "missing", "unreadable")


def _shift_mm(r) -> float | None:
    if r["status"] != "ok" or r["old_centroid_e"] is None:
        return None
    d = np.array([r["centroid_e"] - r["old_centroid_e"], r["centroid_n"] - r["old_centroid_n"],
                  r["centroid_u"] - r["old_centroid_u"]])
    return float(np.linalg.norm(d) * 1e3)


def _rms(values: list[float | None]) -> float | None:
    v = [x for x in values if x is not None and math.isfinite(x)]
    return float(np.sqrt(np.mean(np.square(v)))) if v else None


def _stats(values: list[float]) -> dict:
    if not values:
        return {"median": None, "p95": None, "max": None}
    a = np.asarray(values, float)
    return {"median": float(np.median(a)), "p95": float(np.percentile(a, 95)), "max": float(a.max())}


def summary(db: ReprocessDb) -> dict:
    """The figures of a reprocessing (the command's JSON, docs/reprocess.md): pairs by outcome,
    heliostats, models refitted, ``changed`` (ids), centroid shift statistics (mm) and the
    field's predicted daytime error (mrad, RMS over heliostats) with the old and the new models."""
    pairs, models = db.pair_rows(), db.model_rows()
    counts = dict.fromkeys(STATUSES, 0)
    for r in pairs:
        counts[r["status"]] += 1
    shifts = [s for r in pairs if (s := _shift_mm(r)) is not None]
    new_pred = [r["new_predicted_mrad"] if r["refit"] else r["old_predicted_mrad"] for r in models]
    return {
        "pairs": len(pairs), "measurements": counts["ok"], "no_beam": counts["no_beam"],
        "missing": counts["missing"], "unreadable": counts["unreadable"],
        "heliostats": len(models), "models_refit": sum(1 for r in models if r["refit"]),
        "changed": [r["heliostat_id"] for r in models if r["changed"]],
        "recognition_rerun": any(r["matched"] for r in pairs),
        "centroid_shift_mm": _stats(shifts),
        "daytime_predicted_mrad": {"old": _rms([r["old_predicted_mrad"] for r in models]),
                                   "new": _rms(new_pred)},
    }


def _per_heliostat(db: ReprocessDb) -> list[dict]:
    rows: dict[str, dict] = {}
    for r in db.model_rows():
        rows[r["heliostat_id"]] = {
            "heliostat": r["heliostat_id"], **dict.fromkeys(STATUSES, 0), "shifts": [],
            "refit": bool(r["refit"]), "changed": bool(r["changed"]), "moved": json.loads(r["moved_json"]),
            "new_residual_mrad": r["new_residual_mrad"], "n_measurements": r["new_n_measurements"],
            "old_predicted_mrad": r["old_predicted_mrad"], "new_predicted_mrad": r["new_predicted_mrad"],
            "old": json.loads(r["old_params_json"] or "{}"), "new": json.loads(r["new_params_json"] or "{}"),
            "sigma": json.loads(r["new_sigma_json"] or "{}")}
    for r in db.pair_rows():
        h = rows.get(r["heliostat_id"])
        if h is None:
            continue
        h[r["status"]] += 1
        if (s := _shift_mm(r)) is not None:
            h["shifts"].append(s)
    return list(rows.values())


def _f(v, digits: int = 3) -> str:
    return "" if v is None else f"{v:.{digits}f}"


def write_report(db: ReprocessDb, out: Path, figures: dict, *, plot: bool = True) -> Path:
    """Write the report files (module docstring) into ``out`` and return it."""
    out.mkdir(parents=True, exist_ok=True)
    hel = _per_heliostat(db)
    cols = ["heliostat", *STATUSES, "shift_median_mm", "shift_max_mm", "refit", "changed", "moved_terms",
            "new_residual_mrad", "n_measurements", "old_predicted_mrad", "new_predicted_mrad"]
    table = [[h["heliostat"], *(h[s] for s in STATUSES),
              _f(float(np.median(h["shifts"])) if h["shifts"] else None), _f(max(h["shifts"], default=None)),
              int(h["refit"]), int(h["changed"]), " ".join(sorted(h["moved"])), _f(h["new_residual_mrad"]),
              h["n_measurements"] or 0, _f(h["old_predicted_mrad"]), _f(h["new_predicted_mrad"])]
             for h in hel]
    _csv(out / "heliostats.csv", cols, table)
    terms = []
    for h in hel:
        for key in sorted(set(h["old"]) | set(h["new"])):
            o, n, s = h["old"].get(key), h["new"].get(key), h["sigma"].get(key)
            move = abs(n - (o or 0.0)) / s if n is not None and s else None
            terms.append([h["heliostat"], key, _f(o, 5), _f(n, 5), _f(s, 5), _f(move, 2)])
    _csv(out / "models.csv", ["heliostat", "term", "old", "new", "sigma_new", "move_sigma"], terms)
    bad = [[r["measurement_id"], r["heliostat_id"], r["status"], r["detail"]] for r in db.pair_rows()
           if r["status"] != "ok"]
    _csv(out / "pairs.csv", ["measurement_id", "heliostat", "status", "detail"], bad)
    write_atomic(out / "reprocess.md", lambda t: t.write_text(_markdown(figures, hel, bad), encoding="utf-8"))
    if plot and hel:
        _plot(out / "reprocess.png", hel)
    return out


def _markdown(s: dict, hel: list[dict], bad: list[list]) -> str:
    shift, day = s["centroid_shift_mm"], s["daytime_predicted_mrad"]
    lines = [
        "# Archive reprocessing", "",
        f"Source `{s.get('db', '')}` → `{s.get('out', '')}`" + (f", pairs measured since {s['since']}"
                                                             if s.get("since") else ""), "",
        "| figure | value |", "| --- | --- |",
        f"| frame pairs | {s['pairs']} |",
        f"| re-analysed with a beam | {s['measurements']} |",
        f"| no beam found now | {s['no_beam']} |",
        f"| frames missing | {s['missing']} |",
        f"| frames unreadable | {s['unreadable']} |",
        f"| heliostats | {s['heliostats']} |",
        f"| models refitted | {s['models_refit']} |",
        f"| models changed (a term moved by more than its σ) | {len(s['changed'])} |",
        f"| centroid shift, median / p95 / max (mm) | {_f(shift['median'], 2)} / {_f(shift['p95'], 2)} / "
        f"{_f(shift['max'], 2)} |",
        f"| predicted daytime error, RMS over heliostats (mrad): old → new | {_f(day['old'])} → "
        f"{_f(day['new'])} |", ""]
    if s.get("config_changed"):
        lines += [f"Configuration files changed since recording (the current file was used) for: "
                  f"{', '.join(s['config_changed'])}.", ""]
    changed = [h for h in hel if h["changed"]]
    lines += ["## Models changed", ""]
    if changed:
        lines += ["| heliostat | term: old → new (σ) | predicted daytime old → new (mrad) |",
                  "| --- | --- | --- |"]
        for h in changed:
            moved = "; ".join(f"{k}: {o:.3f} → {n:.3f} ({sg:.3f})"
                              for k, (o, n, sg) in sorted(h["moved"].items()))
            lines.append(f"| {h['heliostat']} | {moved or 'new model'} | {_f(h['old_predicted_mrad'])} → "
                         f"{_f(h['new_predicted_mrad'])} |")
    else:
        lines.append("None.")
    top = sorted((h for h in hel if h["shifts"]), key=lambda h: -max(h["shifts"]))[:20]
    lines += ["", "## Largest centroid shifts", "", "| heliostat | pairs ok | median (mm) | max (mm) |",
              "| --- | --- | --- | --- |"]
    lines += [f"| {h['heliostat']} | {h['ok']} | {np.median(h['shifts']):.2f} | {max(h['shifts']):.2f} |"
              for h in top]
    lines += ["", f"## Pairs not re-analysed ({len(bad)})", ""]
    lines += [f"- measurement {m} ({h}): {st}, {d}" for m, h, st, d in bad[:200]]
    if len(bad) > 200:
        lines.append(f"- … {len(bad) - 200} more in pairs.csv")
    lines += ["", "Per heliostat: heliostats.csv; per term: models.csv.", ""]
    return "\n".join(lines)


def _csv(path: Path, cols: list[str], rows: list[list]) -> None:
    def w(t: Path) -> None:
        with t.open("w", newline="", encoding="utf-8") as f:
            wr = csv.writer(f)
            wr.writerow(cols)
            wr.writerows(rows)
    write_atomic(path, w)


def _plot(path: Path, hel: list[dict]) -> None:
    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    shifts = [s for h in hel for s in h["shifts"]]
    a.hist(shifts or [0.0], bins=30)
    a.set_xlabel("centroid shift, new − old (mm)")
    a.set_ylabel("pairs")
    pts = [(h["old_predicted_mrad"], h["new_predicted_mrad"]) for h in hel
           if h["old_predicted_mrad"] is not None and h["new_predicted_mrad"] is not None]
    if pts:
        x, y = np.array(pts).T
        b.scatter(x, y, s=12)
        lim = [0.0, float(max(x.max(), y.max())) * 1.05]
        b.plot(lim, lim, "k--", lw=0.8)
    b.set_xlabel("predicted daytime error, old model (mrad)")
    b.set_ylabel("new model (mrad)")
    fig.tight_layout()
    save_figure(fig, path, dpi=100, bbox_inches="tight")
