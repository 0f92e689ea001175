"""Figures of ``heliocal model validate --plot DIR``: how the tracking model does on a real
field's records — each heliostat's held-out error beside the rigid-rotation peer and the
two focal-spot methods' floor, the spread of every term across the field, and each
heliostat's drift over time.

Conventions: errors and terms in mrad (angles) or mm (lengths), each axis one unit; dates UTC.
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from controller.geometry.model.tracking import TERMS
from controller.io.images import pyplot, save_figure


def held_out_figure(report: dict, out: Path, name: str = "held_out.png") -> str:
    """Per heliostat: the model's and the rotation's median held-out error, the floor."""
    plt = pyplot()
    rows = [r for r in report["heliostats"] if r.get("model_mrad") is not None]
    fig, ax = plt.subplots(figsize=(max(6.0, 0.7 * len(rows) + 2.0), 4.0))
    x = np.arange(len(rows))
    ax.bar(x - 0.2, [r["model_mrad"] for r in rows], 0.4, color="#1971c2", label="tracking model")
    ax.bar(x + 0.2, [np.nan if r["rotation_mrad"] is None else r["rotation_mrad"] for r in rows], 0.4,
           color="#adb5bd", label="rigid rotation (peer)")
    floor = [np.nan if r["floor_mrad"] is None else r["floor_mrad"] for r in rows]
    ax.plot(x, floor, "k_", markersize=18, mew=2, label="UTIS vs HeliOS (floor)")
    med = report["field"].get("median_of_medians_model_mrad")
    if med is not None:
        ax.axhline(med, color="#1971c2", ls="--", lw=0.8, label=f"field median {med:.2f}")
    ax.set_xticks(x, [r["heliostat"] for r in rows], rotation=45, ha="right")
    ax.set_ylabel("held-out error of the normal, median, mrad")
    ax.set_title(f"split {report['split']}, {report['train']} training records (open loop)")
    ax.legend(fontsize=8)
    save_figure(fig, out / name, dpi=110, bbox_inches="tight")
    return name


def terms_figure(fits: dict, out: Path, name: str = "terms.png") -> str:
    """Each term's fitted value (±1σ) on every heliostat: the spread a field prior learns.
    ``fits``: heliostat id → ModelFit on all its records."""
    plt = pyplot()
    ids = sorted(fits)
    cols = 4
    rows = int(np.ceil(len(TERMS) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.5 * rows), layout="constrained")
    for k, (ax, t) in enumerate(zip(axes.ravel(), TERMS, strict=False)):
        v = np.array([1e3 * fits[h].model.values[k] for h in ids])
        s = np.array([1e3 * fits[h].sigma[k] for h in ids])
        ok = np.array([fits[h].identified[k] for h in ids])
        y = np.arange(len(ids))
        ax.errorbar(v[ok], y[ok], xerr=s[ok], fmt="o", ms=3, color="#1971c2", lw=0.8)
        ax.plot(v[~ok], y[~ok], "o", ms=3, mfc="none", color="#868e96")
        ax.set_yticks(y, ids if k % cols == 0 else [""] * len(ids), fontsize=6)
        ax.set_xlabel(f"{t.name}, {t.unit}", fontsize=8)
        ax.tick_params(axis="x", labelsize=7)
    for ax in axes.ravel()[len(TERMS):]:
        ax.axis("off")
    fig.suptitle("terms fitted to all records (filled: identified, open: at the prior)", fontsize=9)
    save_figure(fig, out / name, dpi=110, bbox_inches="tight")
    return name


def drift_figure(fits: dict, out: Path, name: str = "drift.png") -> str:
    """Each heliostat's joint references over time, relative to its newest session (mrad)."""
    plt = pyplot()
    fig, (a, b) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for h in sorted(fits):
        f = fits[h]
        if f.drift_mrad is None:
            continue
        when = [datetime.fromtimestamp(t * 86400.0, UTC) for t in f.session_times]
        a.plot(when, f.drift_mrad[:, 0], ".-", ms=3, lw=0.8, label=h)
        b.plot(when, f.drift_mrad[:, 1], ".-", ms=3, lw=0.8, label=h)
    a.set_ylabel("azimuth reference, mrad")
    b.set_ylabel("elevation reference, mrad")
    a.set_title("drift of each heliostat's references (relative to its newest session)")
    a.legend(fontsize=7, ncol=4)
    fig.autofmt_xdate()
    save_figure(fig, out / name, dpi=110, bbox_inches="tight")
    return name


def write_validation_figures(folder: str | Path, report: dict, fits: dict) -> list[str]:
    """Every figure of the module into ``folder`` (created); the file names."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    names = [held_out_figure(report, out)]
    if fits:
        names += [terms_figure(fits, out), drift_figure(fits, out)]
    return names
