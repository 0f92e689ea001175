"""The coarse correction in ``heliocal demo`` (its summary:
:func:`controller.reports.summary.coarse_summary`): the centroid-only twin of the runs it
changed, and (``--uncalibrated MRAD``) the same comparison on a newly installed field.

At the demo plant's own hidden-error scale every first spot is in the camera's view, and the
coarse correction (a clipped spot moved by its estimated centre, docs/recognition.md) has
nothing to do. ``--uncalibrated`` calibrates the same heliostats again on a plant whose hidden
errors have the given scale, where first spots land at the view's edge, once with the config's
coarse correction and once centroid only (same seed: same hidden errors and noise), and reports
iterations per heliostat before/after.
"""

from __future__ import annotations

import argparse
from pathlib import Path

UNCALIBRATED_MAX_MRAD = 200.0  # the simulated plant's limit of its hidden-error scale (a new field's)
# The beam search a commissioning configuration turns on (calibration.search, docs/commissioning.md):
# looks per heliostat, and the 1-σ per axis of a new heliostat's normal error it is told: on the
# simulated field at hidden-error scale S the normal at the aim is off by 1.4 S per axis (RMS over
# 240 heliostats of seeds 0-19: 1.96 S in all); on the real field's first records (--uncalibrated
# real) by 30 mrad (RMS of the 16 Jülich heliostats' 41 mrad, over √2).
SEARCH_LOOKS = 40
SEARCH_SIGMA_PER_MRAD = 1.4
SEARCH_SIGMA_REAL_MRAD = 30.0
# Beams parked beside the target of an uncalibrated field are off by as much as the field's
# errors; at the demo config's 8 m they reach the view and spoil other heliostats' looks.
UNCALIBRATED_STANDBY_OFFSET_M = 16.0


def centroid_only_twin(coarse: dict, cfg, config: Path, out: Path, sim, args: argparse.Namespace) -> None:
    """Adds ``iterations_centroid_only_mean`` (and ``centroid_only_rerun``) to ``coarse``.

    A run without a coarse move made only centroid moves: it is its own centroid-only run. The
    heliostats whose run made one are calibrated again, centroid only, on the same seed (each
    heliostat's hidden errors and noise come from its own generator, whoever else is in the run)
    into ``OUT/centroid-only/``; the mean is over both. No coarse move, no second campaign."""
    from controller.commands.simulated import simulated_campaign, simulation_settings
    from controller.config import load_config

    coarse["iterations_centroid_only_mean"] = coarse["iterations_mean"]
    coarse["centroid_only_rerun"] = []
    redo = coarse["applied_heliostats"]
    if cfg.calibration.coarse_correction is None or not redo:
        return
    plain = config_copy(config, out / "centroid-only", coarse_correction=None)
    twin = plain.parent
    _, again = simulated_campaign(load_config(plain), str(plain), twin, twin / "campaign.db", list(redo),
                                  simulation_settings(seed=args.seed), f"{sim.result.name}-centroid-only",
                                  sequential=args.sequential, library_dir=out)
    its = {r.heliostat_id: r.iterations for r in sim.result.runs}
    its.update({r.heliostat_id: r.iterations for r in again.result.runs})
    truth = {**sim.truth, **again.truth}  # closed loop: the plant's true error after each run
    after = [t.error_after_mrad for h, t in truth.items() if h in its and t.error_after_mrad is not None]
    coarse["iterations_centroid_only_mean"] = round(sum(its.values()) / len(its), 3)
    coarse["centroid_only_rerun"] = list(redo)
    coarse["error_after_centroid_only_mrad"] = {"mean": sum(after) / len(after) if after else None,
                                                "max": max(after) if after else None}


def config_copy(config: Path, out: Path, **calibration) -> Path:
    """A copy of the plant config in ``out/config.yaml`` with these ``calibration`` keys replaced."""
    import yaml

    from controller.io.images import write_atomic

    data = yaml.safe_load(config.read_text(encoding="utf-8"))
    data["calibration"].update(calibration)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "config.yaml"
    write_atomic(path, lambda t: t.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8"))
    return path


def uncalibrated_scale(text: str) -> float | str:
    """``--uncalibrated``: ``real`` (the real field's first records) or a scale in (0, 200] mrad."""
    from controller.commands._numbers import Number

    return "real" if text == "real" else Number(0, UNCALIBRATED_MAX_MRAD, lo_open=True)(text)


def uncalibrated_field(config: Path, out: Path, ids: list[str], seed: int, scale_mrad: float | str) -> dict:
    """The heliostats ``ids`` calibrated on a plant with hidden errors of ``scale_mrad``
    (:class:`simplant.settings.SimulationSettings`), with the config's coarse correction and
    centroid only, into ``OUT/uncalibrated/SCALE/{coarse,centroid-only}/`` (SCALE: ``real`` or
    e.g. ``50mrad``); parked beams
    :data:`UNCALIBRATED_STANDBY_OFFSET_M` from the target (or the config's, if farther).

    Returns (closed loop; final errors from the plant's truth): ``tracking_error_mrad``,
    ``threshold``, ``heliostats``, ``clipped_first_looks``, ``applied``, ``applied_heliostats``,
    ``iterations_mean`` / ``iterations_centroid_only_mean`` (measurements per heliostat),
    ``corrections_mean`` / ``corrections_centroid_only_mean`` (corrective moves per heliostat),
    ``calibrated`` / ``calibrated_centroid_only``, ``error_after_mrad`` /
    ``error_after_centroid_only_mrad`` (mean, max)."""
    from controller.commands.simulated import simulated_campaign, simulation_settings
    from controller.config import load_config
    from controller.reports.first_light import first_light, write_first_light

    base = load_config(config).calibration
    standby = max(base.standby_offset_m, UNCALIBRATED_STANDBY_OFFSET_M)
    real = scale_mrad == "real"
    sigma = SEARCH_SIGMA_REAL_MRAD if real else SEARCH_SIGMA_PER_MRAD * float(scale_mrad)
    search = {"max_looks": SEARCH_LOOKS, "normal_sigma_mrad": sigma}
    settings = (simulation_settings(seed=seed, hidden_errors="first-light") if real
                else simulation_settings(seed=seed, tracking_error_mrad=scale_mrad))
    res: dict = {"tracking_error_mrad": scale_mrad, "threshold": base.coarse_correction,
                 "heliostats": len(ids), "search": search}
    # one folder per scale: another scale in the same OUT is another field, never a resume of
    # this one (whose configuration, written first, would be overwritten and then refused)
    field = out / "uncalibrated" / ("real" if real else f"{float(scale_mrad):g}mrad")
    for name, threshold in (("coarse", base.coarse_correction), ("centroid-only", None)):
        path = config_copy(config, field / name, coarse_correction=threshold,
                           standby_offset_m=standby, search=search)
        s, sim = simulated_campaign(load_config(path), str(path), path.parent, path.parent / "campaign.db",
                                    ids, settings, f"uncalibrated-{name}-seed{seed}", library_dir=out)
        c = s["coarse_correction"]
        suffix = "" if name == "coarse" else "_centroid_only"
        if name == "coarse":
            res |= {k: c[k] for k in ("clipped_first_looks", "applied", "applied_heliostats")}
            res["heliostats_per_hour"] = s["heliostats_per_hour"]
            res["beam_safety"] = beam_safety(sim, base.target)
            fl = first_light(s["db"], sim.result.campaign_id)
            res["search_steps"] = fl["totals"]["search_looks"]
            res["search_s"] = fl["totals"]["search_s"]
            res["first_light"] = fl
            res["first_light_report"] = str(write_first_light(fl, path.parent / "report"))
        res |= {f"iterations{suffix}_mean": c["iterations_mean"],
                f"corrections{suffix}_mean": c["corrections_mean"], f"calibrated{suffix}": s["calibrated"],
                f"error_after{suffix}_mrad": s["error_after_mrad"]}
    return res


def beam_safety(sim, target: str) -> dict:
    """The plant truth's beam-safety monitor over a simulated campaign on ``target``: ``samples``,
    ``violations`` (samples with more beams on a target than allowed), ``max_beams_on_target``,
    and the spans a beam spent on the other targets (``other_target_spans``, ``other_target_s``:
    an unmeasured heliostat's beam lands where the nominal model does not put it)."""
    other = [s for tid, spans in sim.on_target.items() if tid != target for s in spans]
    return {**{k: sim.safety.get(k) for k in ("samples", "violations", "max_beams_on_target")},
            "other_target_spans": len(other), "other_target_s": round(sum(b - a for a, b, _ in other), 1)}


def print_uncalibrated(con, u: dict) -> None:
    """One line per comparison of :func:`uncalibrated_field` on the rich console ``con``."""
    def f(v) -> str:
        return "-" if v is None else f"{v:.2f}"

    scale = u["tracking_error_mrad"]
    con.print(f"uncalibrated field (hidden errors {scale if scale == 'real' else f'{scale:g} mrad'}): "
              f"{u['clipped_first_looks']} of {u['heliostats']} first looks clipped, coarse correction "
              f"applied on {u['applied']}; iterations per heliostat {f(u['iterations_mean'])} with, "
              f"{f(u['iterations_centroid_only_mean'])} centroid only; corrective moves "
              f"{f(u['corrections_mean'])} vs {f(u['corrections_centroid_only_mean'])}; calibrated "
              f"{u['calibrated']} vs {u['calibrated_centroid_only']}; final error (truth) mean "
              f"{f(u['error_after_mrad']['mean'])} vs {f(u['error_after_centroid_only_mrad']['mean'])} mrad; "
              f"beam search {u['search_steps']} looks, {u['search_s']:.0f} s; "
              f"{u['beam_safety']['violations']} beam-safety violations (plant truth); "
              f"first light report {u['first_light_report']}")
