"""The figures of a night's morning report that stay readable at any field size: the field
map coloured by predicted daytime error, the distributions, and thumbnails of a few heliostats'
frames (never one per heliostat: a field of 10,000 is read from its map and its worst few).

Conventions: positions ENU metres (x east, y north), errors mrad.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from controller.io.images import pyplot, save_figure
from controller.reports.campaign import write_thumbnail
from controller.storage.checks import resolved_image_path
from controller.storage.db import CampaignStore
from controller.storage.trends import heliostat_trends

LABEL_ALL = 60  # up to this many heliostats every one is named on the map
LABEL_WORST = 20  # beyond, the ones with the largest predicted error (the report's worst table)


def field_map(rows: list[dict], out: Path, name: str = "field_map.png") -> str:
    """Every heliostat at its position, coloured by the daytime RMS its model predicts; those
    with no measurable geometry tonight are crossed. Each heliostat is named beside its dot on a
    field of at most :data:`LABEL_ALL`, else the :data:`LABEL_WORST` with the largest predicted
    error are (the rest are read from the report's tables). Returns the file name."""
    plt = pyplot()
    e = np.array([r["east_m"] for r in rows], float)
    n = np.array([r["north_m"] for r in rows], float)
    v = np.array([np.nan if r["predicted_rms_mrad"] is None else r["predicted_rms_mrad"] for r in rows],
                 float)
    fig, ax = plt.subplots(figsize=(7.5, 6))
    size = float(np.clip(4000.0 / max(len(rows), 1), 1.0, 40.0))
    known = np.isfinite(v)
    hi = float(np.nanpercentile(v, 99)) if known.any() else 1.0
    sc = ax.scatter(e[known], n[known], c=v[known], s=size, cmap="viridis", vmin=0.0, vmax=max(hi, 1e-3),
                    linewidths=0)
    fig.colorbar(sc, ax=ax, label="predicted daytime RMS, mrad (open loop)")
    lost = np.array([bool(r["unmeasurable"]) for r in rows])
    if lost.any():
        ax.scatter(e[lost], n[lost], marker="x", s=max(size, 6.0), color="#c92a2a", linewidths=0.8,
                   label=f"no measurable geometry tonight ({int(lost.sum())})")
        ax.legend(loc="lower left", fontsize=8)
    ax.plot([0.0], [0.0], marker="^", color="k", markersize=8)
    named = range(len(rows)) if len(rows) <= LABEL_ALL else \
        sorted(np.flatnonzero(known), key=lambda i: -v[i])[:LABEL_WORST]
    for i in named:
        ax.annotate(rows[i]["heliostat"], (e[i], n[i]), xytext=(0, 5), textcoords="offset points",
                    ha="center", va="bottom", fontsize=7 if len(rows) <= 30 else 6)
    ax.set_aspect("equal")
    ax.margins(0.08)  # room for the names of the outermost heliostats
    if len(rows) > LABEL_ALL:
        ax.set_title(f"named: the {min(LABEL_WORST, int(known.sum()))} with the largest predicted error",
                     fontsize=9)
    ax.set_xlabel("east, m")
    ax.set_ylabel("north, m")
    save_figure(fig, out / name, dpi=110, bbox_inches="tight")
    return name


def distributions(rows: list[dict], out: Path, name: str = "distributions.png") -> str:
    """Histograms of the predicted daytime RMS and of the geometries measured per heliostat."""
    from matplotlib.ticker import MaxNLocator

    plt = pyplot()
    v = np.array([r["predicted_rms_mrad"] for r in rows if r["predicted_rms_mrad"] is not None], float)
    got = np.array([r["measured"] for r in rows], int)
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.4))
    if v.size:
        a.hist(v, bins=min(60, max(10, int(np.sqrt(v.size)))), color="#1971c2")
        a.axvline(float(np.percentile(v, 95)), color="k", lw=0.8, ls="--", label="p95")
        a.legend(fontsize=8)
    a.set_xlabel("predicted daytime RMS per heliostat, mrad")
    a.set_ylabel("heliostats")
    for ax in (a, b):
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))  # counts of heliostats
    counts = np.bincount(got, minlength=1) if got.size else np.zeros(1, int)
    b.bar(np.arange(len(counts)), counts, color="#2f9e44")
    b.set_xlabel("geometries measured tonight")
    b.set_ylabel("heliostats")
    save_figure(fig, out / name, dpi=110, bbox_inches="tight")
    return name


def thumbnails(store: CampaignStore, heliostat_ids: list[str], out: Path) -> dict[str, str]:
    """Per heliostat of ``heliostat_ids``: the thumbnail (path relative to ``out``) of the HIGH
    frame of its latest measurement (tonight's when it was measured tonight), scaled to at most
    :data:`controller.reports.campaign.THUMB_PX` wide. One query for all of them; frames no
    longer on disk are left out."""

    if not heliostat_ids:
        return {}
    marks = ",".join("?" * len(heliostat_ids))
    rows = store.query(
        "SELECT r.heliostat_id AS hid, i.path AS path FROM images i "
        "JOIN measurements m ON i.measurement_id=m.id JOIN heliostat_runs r ON m.run_id=r.id "
        f"WHERE i.kind='high' AND r.heliostat_id IN ({marks}) ORDER BY m.id", tuple(heliostat_ids))
    # The latest frame wins; paths are stored relative to the database (or absolute, before that).
    last = {r["hid"]: resolved_image_path(store.path, r["path"]) for r in rows}
    out_paths = {}
    for hid, path in last.items():
        rel = f"thumbs/{hid}.png"
        if not write_thumbnail(path, out / rel):
            continue
        out_paths[hid] = rel
    return out_paths


TREND_LINES = 10  # heliostats drawn one line each in the trend: the worst tonight


def trend(store: CampaignStore, night_index: int, rows: list[dict], nights: list, out: Path,
          name: str = "trend.png") -> str | None:
    """Night by night up to ``night_index``, for the :data:`TREND_LINES` heliostats of ``rows``
    with the largest predicted daytime RMS tonight (all of a smaller field): the daytime RMS
    each model predicted after the night (with the field's, from the nights' summaries) and the
    mean pointing error of the night's first looks (log scale: the calibration night's
    uncorrected error is ten times a planned night's). None with fewer than two nights."""
    shown = [n for n in nights if n.index <= night_index]
    if len(shown) < 2:
        return None
    worst = sorted((r for r in rows if r["predicted_rms_mrad"] is not None),
                   key=lambda r: -r["predicted_rms_mrad"])[:TREND_LINES]
    series = heliostat_trends(store, [r["heliostat"] for r in worst])
    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.6))
    field = [(n.index, n.summary.get("daytime_error_predicted_mrad", {}).get("rms")) for n in shown]
    field = [(k, v) for k, v in field if v is not None]
    if field:
        a.plot(*zip(*field, strict=True), "k-", lw=2.5, label="field (RMS)", zorder=3)
    for hid, pts in series.items():
        pred = [(p["night"], p["predicted_rms_mrad"]) for p in pts
                if p["night"] <= night_index and p["predicted_rms_mrad"] is not None]
        look = [(p["night"], p["first_look_error_mrad"]) for p in pts
                if p["night"] <= night_index and p["first_look_error_mrad"] is not None]
        colour = None
        if pred:
            colour = a.plot(*zip(*pred, strict=True), "o-", lw=1, ms=3, label=hid)[0].get_color()
        if look:
            b.plot(*zip(*look, strict=True), "o-", lw=1, ms=3, color=colour)
    a.set_ylabel("predicted daytime RMS, mrad")
    a.set_ylim(bottom=0)
    b.set_ylabel("mean first-look error, mrad (measured)")
    b.set_yscale("log")
    for ax in (a, b):
        ax.set_xlabel("night")
        ax.set_xticks([n.index for n in shown])
        ax.grid(alpha=0.3)
    a.set_title("predicted by each night's models", fontsize=9)
    b.set_title("measured at each night's first looks", fontsize=9)
    fig.suptitle(f"The {len(worst)} heliostats with the largest predicted error tonight"
                 if len(rows) > len(worst) else "Every heliostat", fontsize=10)
    fig.legend(*a.get_legend_handles_labels(), loc="center left", bbox_to_anchor=(1.0, 0.5), fontsize=8)
    fig.tight_layout()
    save_figure(fig, out / name, dpi=110, bbox_inches="tight")
    return name
