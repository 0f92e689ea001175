"""The tables of ``heliocal model validate``: leave-one-out on one heliostat's records, and a
split over one heliostat or a PAINT folder's field (docs/tracking-model.md, "Validation")."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from controller.commands._id_lists import split_ids
from controller.errors import InputError


def loo_report(args: argparse.Namespace) -> dict:
    """Leave-one-out on the records of one heliostat, printed unless ``--json``; the JSON dict."""
    from controller.geometry.aiming import aim_normal, angle_mrad
    from controller.geometry.model.validation import leave_one_out
    from controller.geometry.paint_io import read_paint_set

    if not args.heliostat_properties or not args.towers:
        raise InputError("model validate: records need --heliostat-properties and --towers")
    ps = read_paint_set(args.records, args.heliostat_properties, args.towers)
    kin, records = ps.kinematics, ps.records
    folds = leave_one_out(kin, [r.sample for r in records], noise_mrad=args.noise_mrad)
    rows = []
    for f, r in zip(folds, records, strict=True):
        floor = None
        if "HeliOS" in r.focal_spots:
            c = kin.mirror_center(r.sample.az_steps, r.sample.el_steps)
            floor = float(angle_mrad(aim_normal(r.sample.source_dir, c, r.focal_spots["UTIS"]),
                                     aim_normal(r.sample.source_dir, c, r.focal_spots["HeliOS"])))
        rows.append({"record": Path(r.source).name, "held_out_mrad": f.held_out_mrad,
                     "uncalibrated_mrad": f.uncalibrated_mrad, "methods_disagree_mrad": floor,
                     "identified": f.fit.identified_terms()})
    held = np.array([r["held_out_mrad"] for r in rows])
    unc = np.array([r["uncalibrated_mrad"] for r in rows])
    summary = {"held_out_rms_mrad": float(np.sqrt(np.mean(held**2))),
               "uncalibrated_rms_mrad": float(np.sqrt(np.mean(unc**2))),
               "worst_ratio": float(np.min(unc / np.maximum(held, 1e-9)))}
    if not args.json:
        print(f"  {'held-out record':<40}{'held-out':>10}{'uncal.':>10}{'UTIS/HeliOS':>13}"
              "  (normal error, mrad)")
        for r in rows:
            fl = "-" if r["methods_disagree_mrad"] is None else f"{r['methods_disagree_mrad']:.2f}"
            print(f"  {r['record']:<40}{r['held_out_mrad']:>10.2f}{r['uncalibrated_mrad']:>10.2f}{fl:>13}")
        print(f"  RMS {summary['held_out_rms_mrad']:.2f} mrad held out vs "
              f"{summary['uncalibrated_rms_mrad']:.2f} uncalibrated; every record at least "
              f"{summary['worst_ratio']:.1f}x better")
    return {"folds": rows, **summary}


def paint_sets(args: argparse.Namespace) -> list:
    """The heliostats to validate: one from its records, or every one (``--heliostats``) of a
    PAINT folder, each with its records' times when there are timestamps."""
    from controller.geometry.paint_io import read_paint_set, read_timestamps
    from controller.storage.paint.folder import heliostat_folders

    if args.paint_dir:
        root = Path(args.paint_dir)
        folders = heliostat_folders(root)
        towers = args.towers or str(root / "tower-measurements.json")
        stamps_file = args.timestamps or (root / "timestamps.json")
        stamps = read_timestamps(stamps_file) if Path(stamps_file).is_file() else None
        wanted = list(folders)
        if args.heliostats:
            wanted = split_ids(args.heliostats, "--heliostats")
        unknown = [h for h in wanted if h not in folders]
        if unknown:
            raise InputError(f"{root}: no heliostat {', '.join(unknown)} (known: {', '.join(folders)})")
        return [read_paint_set([str(p) for p in folders[h][1]], folders[h][0], towers, timestamps=stamps,
                               methods=("UTIS", "HeliOS")) for h in wanted]
    if not args.heliostat_properties or not args.towers:
        raise InputError("model validate: records need --heliostat-properties and --towers")
    stamps = read_timestamps(args.timestamps) if args.timestamps else None
    return [read_paint_set(args.records, args.heliostat_properties, args.towers, timestamps=stamps,
                           methods=("UTIS", "HeliOS"))]


def _floor(records, position: np.ndarray) -> float | None:
    """Median UTIS/HeliOS disagreement (normal from the heliostat at ``position``, mrad) over
    ``records`` having both."""
    from controller.geometry.aiming import aim_normal, angle_mrad

    both = [r for r in records if {"UTIS", "HeliOS"} <= set(r.focal_spots)]
    if not both:
        return None
    return float(np.median([angle_mrad(aim_normal(r.sample.source_dir, position, r.focal_spots["UTIS"]),
                                       aim_normal(r.sample.source_dir, position, r.focal_spots["HeliOS"]))
                            for r in both]))


def heliostat_row(ps, split: str, args: argparse.Namespace, prior, walk) -> dict:
    """One heliostat's row of the split table (or its reason for having none)."""
    from controller.geometry.model.splits import split as split_records
    from controller.geometry.model.tracking import TrackingModel
    from controller.geometry.model.validation import Targets, held_out

    recs = ps.records
    times = [r.sample.time_days for r in recs]
    timed = all(v is not None for v in times)
    # Without timestamps the records' order (PAINT ids rise with time) stands for time.
    t = np.array(times, float) if timed else np.arange(len(recs), dtype=float)
    row: dict = {"heliostat": ps.heliostat_id, "records": len(recs)}
    try:
        train, val, test = split_records(split, t, [r.sun_azimuth_deg for r in recs],
                                         [r.sun_elevation_deg for r in recs], n_train=args.train,
                                         n_val=args.val if split not in ("time", "first") else 0,
                                         n_test=args.val)
    except ValueError as exc:
        return {**row, "skipped": str(exc)}
    out = np.concatenate([val, test]).astype(int)
    targets = Targets(np.array([recs[i].target.center_enu for i in out]),
                      np.array([recs[i].target.normal for i in out]))
    try:
        res = held_out(ps.kinematics, [recs[i].sample for i in train], [recs[i].sample for i in out], targets,
                       noise_mrad=args.noise_mrad, prior=TrackingModel(prior.mean) if prior else None,
                       prior_sigma=prior.sigma if prior else None, drift=walk if timed else None)
    except InputError as exc:
        return {**row, "refused": str(exc)}
    med = lambda a: float(np.nanmedian(a)) if np.isfinite(a).any() else None  # noqa: E731
    return {**row, "train": len(train), "held_out": len(out), "model_mrad": med(res.model_mrad),
            "rotation_mrad": med(res.rotation_mrad), "nominal_mrad": med(res.nominal_mrad),
            "floor_mrad": _floor([recs[i] for i in out], ps.kinematics.position),
            "notes": list(res.fit.notes),
            "errors_mrad": [None if not np.isfinite(v) else float(v) for v in res.model_mrad],
            "rotation_errors_mrad": [None if not np.isfinite(v) else float(v) for v in res.rotation_mrad]}


def field_report(sets: list, split: str, args: argparse.Namespace) -> dict:
    """The split table of every heliostat in ``sets`` and the field's medians of their medians."""
    from controller.commands.model.fit import DRIFT_MRAD
    from controller.geometry.model.drift import PAINT_JUMP_RAD, RandomWalk
    from controller.geometry.model.field_prior_io import read_prior

    prior = read_prior(args.prior) if args.prior else None
    walk = RandomWalk(DRIFT_MRAD * 1e-3, PAINT_JUMP_RAD)
    rows = []
    for ps in sets:
        rows.append(heliostat_row(ps, split, args, prior, walk))
        if len(sets) > 1 and not args.json:
            print(f"  {ps.heliostat_id}: done ({len(rows)}/{len(sets)})", file=sys.stderr)
    done = [r for r in rows if r.get("model_mrad") is not None]
    field = {"heliostats": len(done)}
    for key in ("model_mrad", "rotation_mrad", "nominal_mrad", "floor_mrad"):
        vals = [r[key] for r in done if r.get(key) is not None]
        field[f"median_of_medians_{key}"] = float(np.median(vals)) if vals else None
    if field["median_of_medians_model_mrad"] and field["median_of_medians_rotation_mrad"]:
        field["model_over_rotation"] = (field["median_of_medians_model_mrad"]
                                        / field["median_of_medians_rotation_mrad"])
    return {"split": split, "train": args.train, "val": args.val, "prior": args.prior, "heliostats": rows,
            "field": field}


def full_fits(sets: list, args: argparse.Namespace) -> dict:
    """Each heliostat's model fitted to all its records (for the term and drift figures); a
    heliostat the fit refuses is left out."""
    from controller.commands.model.fit import DRIFT_MRAD
    from controller.geometry.model.drift import PAINT_JUMP_RAD, RandomWalk
    from controller.geometry.model.fit import fit_model

    walk = RandomWalk(DRIFT_MRAD * 1e-3, PAINT_JUMP_RAD)
    fits = {}
    for ps in sets:
        samples = [r.sample for r in ps.records]
        timed = all(s.time_days is not None for s in samples)
        try:
            fits[ps.heliostat_id] = fit_model(ps.kinematics, samples, noise_mrad=args.noise_mrad,
                                              drift=walk if timed else None)
        except InputError:
            continue
    return fits


def print_field(report: dict) -> None:
    print(f"  split {report['split']}, {report['train']} training records; held-out error of the mirror "
          "normal (median, mrad)")
    print(f"  {'heliostat':<10}{'train':>6}{'held':>6}{'model':>9}{'rotation':>10}{'nominal':>9}{'floor':>8}")
    for r in report["heliostats"]:
        if r.get("model_mrad") is None:
            print(f"  {r['heliostat']:<10}  {r.get('skipped') or r.get('refused')}")
            continue
        fl = "-" if r["floor_mrad"] is None else f"{r['floor_mrad']:.2f}"
        rot = "-" if r["rotation_mrad"] is None else f"{r['rotation_mrad']:.2f}"
        nom = "-" if r["nominal_mrad"] is None else f"{r['nominal_mrad']:.1f}"
        print(f"  {r['heliostat']:<10}{r['train']:>6}{r['held_out']:>6}{r['model_mrad']:>9.2f}{rot:>10}"
              f"{nom:>9}{fl:>8}")
    f = report["field"]
    if f["heliostats"]:
        ratio = f" ({f['model_over_rotation']:.2f}× the rotation's)" if f.get("model_over_rotation") else ""
        print(f"  field of {f['heliostats']}: median of medians {f['median_of_medians_model_mrad']:.2f} mrad"
              f"{ratio}; rotation {f['median_of_medians_rotation_mrad'] or float('nan'):.2f}, floor "
              f"{f['median_of_medians_floor_mrad'] or float('nan'):.2f}")
