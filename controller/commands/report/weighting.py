"""``heliocal report weighting``: the weighting-function study (HDR paper Fig. 13).

Contract::

    heliocal report weighting --pairs 20 --out DIR [--seed S] [--json]

The study itself is :mod:`simplant.studies.weighting` (it needs the simulator's noise-free
scene as its truth):

1. The simulated double-CCD camera (the demo plant's camera, its true CRF) captures ``--pairs``
   pairs of one fixed scene: the beam spot of heliostat ``--heliostat`` under ``--source``
   (default: the sun, high in the south) on a 3 m window of the calibration target, rendered by
   :func:`simplant.optics.render_spot` (2 M rays, 1 px Gaussian camera PSF), plus
   diffuse ambient light on the target, framed with a dark border (the target mask). The
   brightness is set so that LOW peaks at ``--low-peak`` (default 80 %) of its range, so that
   HIGH saturates in the core.
2. Each pair is merged with every weighting function.
3. Pixels outside the target are masked.
4. The HDR image is thresholded at 0.45, 0.50, ..., 0.90 of its peak.
5. The centroid of the segmented spot is computed (:func:`controller.imaging.beam.analyze`,
   no background subtraction, so that only the merge differs).
6. The RMS distance of the centroids to their mean is reported per (weighting, threshold).

DIR receives ``weighting_study.csv`` (weighting, threshold, rms_px, bias_px, mean_x_px, mean_y_px,
pairs; ``bias_px`` = distance of the mean centroid from the centroid of the noise-free scene),
``rms_vs_threshold.png``, ``weighting_functions.png`` and ``profiles.png``. ``--json`` prints
``{"thresholds": [...], "rms_px": {"raised-cosine": [...], ...}}``.
"""

from __future__ import annotations

import sys

from controller.commands._numbers import SEED, Number
from controller.commands.common import add_config_option, add_json_option, output_dir, print_json
from controller.errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser("weighting", help="weighting-function study: centroid RMS vs threshold",
                              description="Reproduce the HDR paper's Fig. 13 on the simulated camera.")
    p.add_argument("--pairs", type=Number(1, 1000, integer=True), default=20,
                   help="pairs captured of the same scene (default 20)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--seed", type=SEED, default=0, help="noise seed (default 0)")
    p.add_argument("--heliostat", default=None, help="heliostat whose spot is imaged (default: first)")
    p.add_argument("--source", default=None, help="light source id (default: the sun, else the lamp)")
    p.add_argument("--low-peak", type=Number(0.05, 1), default=None, metavar="FRACTION",
                   help="LOW's peak signal as a fraction of its range (default 0.8: HIGH saturates in "
                        "the core; below ~0.47 nothing saturates)")
    add_config_option(p)
    add_json_option(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from controller.commands.simulated import weighting_study
    from controller.config import load_config

    weighting = weighting_study()

    if not 2 <= args.pairs <= 1000:
        raise InputError(f"--pairs must be in 2..1000, got {args.pairs}")
    if args.low_peak is not None and not 0.05 <= args.low_peak <= 1.0:
        raise InputError(f"--low-peak must be a fraction in [0.05, 1], got {args.low_peak}")
    out = output_dir(args.out)
    cfg = load_config(args.config)
    if args.heliostat:
        cfg.heliostat(args.heliostat)
    if args.source and args.source not in {s.id for s in cfg.light_sources}:
        raise InputError(f"--source {args.source!r}: no such light source in {args.config}")
    low_peak = weighting.LOW_PEAK_FRACTION if args.low_peak is None else args.low_peak
    interactive = sys.stderr.isatty() and not args.json
    if interactive:
        from rich.progress import Progress

        with Progress(transient=True) as prog:
            task = prog.add_task("capturing and merging pairs", total=args.pairs)
            study = weighting.run_study(cfg, args.pairs, args.seed, args.heliostat,
                                        lambda: prog.advance(task), args.source, low_peak)
    else:
        study = weighting.run_study(cfg, args.pairs, args.seed, args.heliostat, source_id=args.source,
                                    low_peak=low_peak)
    out.mkdir(parents=True, exist_ok=True)
    weighting.write_csv(out, study)
    weighting.write_plots(out, study)
    result = {"thresholds": study.thresholds, "rms_px": study.rms_px}
    if args.json:
        print_json(result)
    else:
        best = {t: min(study.rms_px, key=lambda w, j=j: study.rms_px[w][j])
                for j, t in enumerate(study.thresholds)}
        print("threshold  " + "  ".join(f"{w[:13]:>13s}" for w in study.rms_px))
        for j, t in enumerate(study.thresholds):
            print(f"{t:9.2f}  " + "  ".join(f"{study.rms_px[w][j]:13.4f}" for w in study.rms_px)
                  + f"   best: {best[t]}")
        print(f"wrote {out}/weighting_study.csv, rms_vs_threshold.png, weighting_functions.png, profiles.png")
    return 0
