"""The morning report's tracking-model section: what the nights measured and what it is worth
for daytime pointing.

For every heliostat of the campaign: its measurements across the whole database (all nights),
the light sources they came from, the latest model's identified terms and training residual,
and the daytime error its covariance predicts (open loop, the yearly sun path, at the target
centre; needs the campaign's configuration file). Written beside the report:

* ``geometries.png``: per heliostat, the mirror normals it was measured at (azimuth/elevation,
  one colour per light source) over the normals daytime tracking needs (grey): coverage of the
  poses the model must predict;
* ``daytime.png``: histogram of the predicted daytime RMS per heliostat and, for a run with
  planned nights, the field's daytime error after each night (true against a simulated
  plant's truth where the campaign's metadata has it, and predicted);
* ``model_terms.csv``: every heliostat's fitted terms with 1-σ.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from controller.calibration.night.daytime import predicted_daytime, sun_path, tracking_steps
from controller.calibration.records import CampaignRecord, MeasurementRecord, ModelRecord
from controller.config import PlantConfig, load_config
from controller.errors import HeliocalError
from controller.geometry.aiming import aim_normal
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model.tracking import TERMS
from controller.geometry.vectors import vector_to_azel
from controller.io.images import pyplot, save_figure, write_atomic
from controller.storage.db import CampaignStore
from controller.storage.field_prints import check_field


def _config(camp: CampaignRecord) -> PlantConfig | None:
    try:
        return load_config(camp.config_path)
    except (HeliocalError, OSError):
        return None  # moved or changed since: the section says what it can without it


def _configured(cfg: PlantConfig, hid: str) -> bool:
    return any(h.id == hid for h in cfg.heliostats)


def _normal_deg(m: MeasurementRecord, position: np.ndarray) -> tuple[float, float]:
    """Azimuth and elevation (deg) of the normal a measurement with a centroid implies."""
    n = aim_normal(np.asarray(m.source_dir, float), position, np.asarray(m.centroid_enu, float))
    return vector_to_azel(n)


def model_section(store: CampaignStore, camp: CampaignRecord, out: Path,
                  accept_field_change: bool = False) -> tuple[list[str], list[tuple[str, str]]]:
    """Markdown lines and (title, png) figures of the section (module docstring). The models are
    applied to the campaign's configuration only if it still describes the field they were
    fitted on (FieldChanged, exit 2, unless ``accept_field_change``)."""
    ids = list(camp.queue)
    cfg = _config(camp)
    if cfg is not None:
        check_field(store, cfg, [h for h in ids if _configured(cfg, h)], camp.config_path,
                    accept=accept_field_change)
    models: dict[str, ModelRecord | None] = {hid: store.latest_model(hid) for hid in ids}
    meas = {hid: store.measurements(heliostat_id=hid) for hid in ids}
    predicted = predicted_daytime(cfg, models) if cfg is not None else None
    lines = ["", "## Tracking model and daytime pointing", ""]
    meta = camp.meta
    if "daytime_error_mrad" in meta:
        d, p = meta["daytime_error_mrad"], meta.get("daytime_error_predicted_mrad", {})
        lines += [f"- open-loop daytime error of the field (sun path of four days, simulated plant's truth): "
                  f"RMS **{d['rms']:.2f}** mrad, p95 {d['p95']:.2f}; predicted from the models' σ: "
                  f"RMS {p.get('rms', float('nan')):.2f}, p95 {p.get('p95', float('nan')):.2f}"]
    for n in meta.get("nights", []):
        lines += [f"- after night {n['night']} ({n['measured']}/{n['planned']} planned geometries measured): "
                  f"true RMS {n['daytime_error_mrad']['rms']:.2f} mrad, predicted "
                  f"{n['daytime_error_predicted_mrad']['rms']:.2f}"]
    if predicted is None:
        lines += [f"- the configuration `{camp.config_path}` cannot be read any more: "
                  "no predicted daytime error"]
    lines += ["", "| heliostat | measurements | light sources | identified terms | training residual mrad | "
              "predicted daytime RMS mrad |", "| --- | --- | --- | --- | --- | --- |"]
    for hid in ids:
        ms, m = meas[hid], models[hid]
        sources = len({tuple(np.round(x.source_pos_enu or x.source_dir, 3)) for x in ms})
        ident = len(m.detail.get("identified", [])) if m else 0
        res = f"{m.residual_mrad:.3f}" if m and m.residual_mrad is not None else "–"
        pred = f"{predicted.per_heliostat[hid]:.2f}" if predicted else "–"
        lines.append(f"| {hid} | {len(ms)} | {sources} | {ident} of {len(TERMS)} | {res} | {pred} |")
    _terms_csv(out / "model_terms.csv", models)
    lines += ["", "Fitted terms with 1-σ: [model_terms.csv](model_terms.csv)."]
    figs = []
    if cfg is not None and any(meas.values()):
        figs.append(_geometry_plot(cfg, ids, meas, models, out))
    if predicted is not None:
        figs.append(_daytime_plot(predicted.per_heliostat, meta.get("nights", []), out))
    return lines, figs


def _terms_csv(path: Path, models: dict[str, ModelRecord | None]) -> None:
    cols = ["heliostat"] + [f"{t.key}{s}" for t in TERMS for s in ("", "_sigma")]
    rows = []
    for hid, m in models.items():
        if m is None:
            continue
        rows.append([hid] + [f"{v:.4f}" if v is not None else "" for t in TERMS
                             for v in (m.params.get(t.key, 0.0), m.sigma.get(t.key))])
    text = "\n".join(",".join(r) for r in [cols, *rows]) + "\n"
    write_atomic(path, lambda t: t.write_text(text, encoding="utf-8"))


def _geometry_plot(cfg: PlantConfig, ids: list[str], meas, models, out: Path) -> tuple[str, str]:
    plt = pyplot()

    path = sun_path(cfg.site)
    target = np.asarray(cfg.target().center_enu_m, float)
    n = len(ids)
    cols = min(4, n)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.8 * rows), squeeze=False, sharex=True,
                             sharey=True)
    colours: dict[str, tuple] = {}
    palette = plt.get_cmap("tab10")
    # Lamps are named by the configuration; a measurement under the sun carries no position.
    names = {tuple(np.round(s.position_enu_m, 2)): s.id for s in cfg.light_sources if s.kind == "lamp"}
    for ax, hid in zip(axes.ravel(), ids, strict=False):
        h = cfg.heliostat(hid)
        pos = np.asarray(h.position_enu_m, float)
        steps, ok = tracking_steps(h, models.get(hid), path.directions, target)
        kin = HeliostatKinematics.from_config(h)
        day = np.array([vector_to_azel(kin.normal(*s)) for s in steps[ok]]).reshape(-1, 2)
        ax.scatter(day[:, 0], day[:, 1], s=3, c="0.8", label="daytime (sun path)")
        for m in meas[hid]:
            if m.centroid_enu is None:
                continue
            if m.source_pos_enu is None:
                key = "sun"
            else:
                pos_key = tuple(np.round(m.source_pos_enu, 2))
                key = names.get(pos_key, f"lamp at {pos_key}")
            colours.setdefault(key, palette(len(colours) % 10))
            az, el = _normal_deg(m, pos)
            ax.scatter([az], [el], s=18, color=colours[key], edgecolor="k", linewidth=0.4)
        ax.set_title(f"{hid}: {len(meas[hid])} measurements", fontsize=9)
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("normal azimuth, deg")
    for ax in axes[:, 0]:
        ax.set_ylabel("normal elevation, deg")
    fig.suptitle("Measured mirror normals (colour: light source) over the normals daytime tracking "
                 "needs (grey)", fontsize=10)
    handles = [plt.Line2D([], [], ls="", marker="o", color=c, markeredgecolor="k", label=key)
               for key, c in colours.items()]
    fig.legend(handles=handles, loc="lower center", ncol=min(8, len(handles)), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    save_figure(fig, out / "geometries.png", dpi=90, bbox_inches="tight")
    return "Measured geometries", "geometries.png"


def _daytime_plot(per: dict[str, float], nights: list[dict], out: Path) -> tuple[str, str]:
    from matplotlib.ticker import MaxNLocator

    plt = pyplot()

    fig, axes = plt.subplots(1, 2 if nights else 1, figsize=(10 if nights else 5.5, 3.6), squeeze=False)
    vals = np.array([v for v in per.values() if np.isfinite(v)])
    ax = axes[0, 0]
    ax.hist(vals, bins=max(5, min(20, len(vals))), color="tab:blue", alpha=0.8)
    ax.set_xlabel("predicted daytime RMS per heliostat, mrad")
    ax.set_ylabel("heliostats")
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))  # counts of heliostats
    ax.set_title("Predicted open-loop daytime error", fontsize=10)
    if nights:
        ax = axes[0, 1]
        k = [n["night"] for n in nights]
        ax.plot(k, [n["daytime_error_mrad"]["rms"] for n in nights], "o-", label="true RMS (simulated plant)")
        ax.plot(k, [n["daytime_error_predicted_mrad"]["rms"] for n in nights], "s--", label="predicted RMS")
        ax.set_xlabel("night")
        ax.set_ylabel("field daytime error, mrad")
        ax.set_xticks(k)
        ax.set_ylim(bottom=0)
        ax.legend(loc="center left", bbox_to_anchor=(1.02, 0.5), fontsize=8)
        ax.set_title("Daytime error after each night", fontsize=10)
    fig.tight_layout()
    save_figure(fig, out / "daytime.png", dpi=90, bbox_inches="tight")
    return "Daytime pointing", "daytime.png"
