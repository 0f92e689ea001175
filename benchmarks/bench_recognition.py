"""Error-case recognition that generalises: recognition rate by held-out split (JSON on stdout).

    .venv/bin/python benchmarks/bench_recognition.py [--seed 1] [--views 8] [--dir DIR]

Renders (:func:`simplant.errorset.write_errorset`, demo config) library images of the 6 error
cases at nine magnitudes 0.5, 0.625, ..., 1.5 on the twelve heliostats of the field's three rows
that are not held out (40-70 m, lamp) and ``--views`` perturbed test views per case on

* six other heliostats (``held-out-heliostat``: H02, H04, H09, H10, H15, H17),
* two library heliostats (``held-out-magnitude``: H08, H13),
* H09 under the sun and H04 under the west lamp (``held-out-geometry``),

each test view with an error size drawn uniformly from 0.5..1.5 (so none equals a library
magnitude). Every library variant is built from a subset of those images (all twelve heliostats
or six of them, H01, H06, H08, H11, H13, H18; all nine sizes or 0.5, 1, 1.5) and scored per split
(:mod:`controller.recognition.splits`): recognition rate (%), unknown rate (%) and n.
For the ``multi-hu`` variants it also reports the magnitude estimate: RMS error of the
interpolated beam pointing error against the truth over correctly recognised views, and the
share and precision of views with confidence >= 0.5 (where a coarse correction would be applied)
with the RMS pointing error before and after applying it. ``--dir`` keeps the rendered set (and
reuses it on the next run).

``--independent [--seeds 1,2,3]``: instead, the independent error set of
:mod:`independent_spots` (a paraxial renderer written apart from ``simplant.optics``; magnitude
0.5-1.5 and spot size x0.7-1.4 vary in the test views, library = 3 magnitudes per case), scored
through the CLI contract (``heliocal library build`` default, ``--features blur-hu``,
``--features multi-blur-hu`` and ``--features hu --whiten no``, ``heliocal report confusion
--json``), plus ablations of the default through the Python API (no interpolation between
magnitudes, no blur views in the whitening, neither) and the default's rate split by the view's
effective magnitude m / spot (inside or outside the library's 0.5-1.5; see docs/recognition.md).

``--campaign [--threshold T] [--heliostats N]``: instead, the coarse correction in the closed
loop on the demo plant as it is. Runs ``heliocal demo --nights 0 --json`` (embedded simulated
plant, demo config, seed ``--seed``) with ``calibration.coarse_correction: T`` and reports its
``coarse_correction`` block (the demo calibrates the heliostats that made a coarse move again,
centroid only). The with/without comparison where first spots are clipped, and the estimator
on shifted spots, is ``benchmarks/bench_coarse.py``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from controller.config import load_config
from controller.io.images import read_image
from controller.recognition.library_io import build_library_from_manifest, read_manifest, write_manifest
from controller.recognition.splits import SPLITS, Coverage
from simplant.errorset import MANIFEST_EXTRA, scene_from_config, write_errorset

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "demo.yaml"
LIBRARY = ("H01", "H03", "H05", "H06", "H07", "H08", "H11", "H12", "H13", "H14", "H16", "H18")
SIX = ("H01", "H06", "H08", "H11", "H13", "H18")
HELD_OUT = ("H02", "H04", "H09", "H10", "H15", "H17")
SIZES = tuple(0.5 + 0.125 * i for i in range(9))
THREE = (0.5, 1.0, 1.5)
VARIANTS = {  # name: (features, whiten, library sizes, library heliostats)
    "multi-hu whitened (default), 12 heliostats x 9 sizes": ("multi-hu", None, SIZES, LIBRARY),
    "multi-hu whitened (default), 6 heliostats x 9 sizes": ("multi-hu", None, SIZES, SIX),
    "multi-hu whitened (default), 6 heliostats x 3 sizes": ("multi-hu", None, THREE, SIX),
    "hu raw (paper), 12 heliostats x 9 sizes": ("hu", False, SIZES, LIBRARY),
    "hu raw (paper), 6 heliostats x 3 sizes": ("hu", False, THREE, SIX),
    "hu whitened, 6 heliostats x 3 sizes": ("hu", True, THREE, SIX),
    "log-hu, 6 heliostats x 3 sizes": ("log-hu", False, THREE, SIX),
    "blur-hu whitened, 6 heliostats x 3 sizes": ("blur-hu", None, THREE, SIX),
    "multi-blur-hu whitened, 6 heliostats x 3 sizes": ("multi-blur-hu", None, THREE, SIX),
}
CONFIDENT = 0.5


def render(out: Path, seed: int, views: int) -> None:
    cfg = load_config(CONFIG)
    lib = [scene_from_config(cfg, h) for h in LIBRARY]
    test = [scene_from_config(cfg, h) for h in (*HELD_OUT, "H08", "H13")]  # two library heliostats
    test += [scene_from_config(cfg, "H09", "sun"), scene_from_config(cfg, "H04", "lamp-west")]
    write_errorset(out, lib, seed=seed, views=views, magnitudes=SIZES, test_scenes=test,
                   test_magnitude_range=(0.5, 1.5))


def library_manifest(out: Path, sizes: tuple[float, ...], heliostats: tuple[str, ...]) -> Path:
    """The library manifest restricted to ``sizes`` and ``heliostats`` (subsets of the rendered ones)."""
    if sizes == SIZES and heliostats == LIBRARY:
        return out / "library.csv"
    rows = [r for r in read_manifest(out / "library.csv")
            if float(r.extra["magnitude"]) in sizes and r.extra["heliostat"] in heliostats]
    path = out / f"library-{len(heliostats)}x{len(sizes)}.csv"
    write_manifest(path, [(str(r.image), r.label, r.az_deg, r.el_deg, *(r.extra[k] for k in MANIFEST_EXTRA))
                          for r in rows], header=("image", "label", "az_deg", "el_deg", *MANIFEST_EXTRA))
    return path


def _rate(ok: np.ndarray) -> float:
    return round(100.0 * float(ok.mean()), 2) if ok.size else float("nan")


def score(out: Path, features: str, whiten: bool | None, sizes: tuple[float, ...],
          heliostats: tuple[str, ...]) -> dict:
    lib = build_library_from_manifest(library_manifest(out, sizes, heliostats), features, whiten=whiten)
    cov = Coverage.of(lib.entries)
    rows = read_manifest(out / "test.csv")
    images = [read_image(r.image) for r in rows]
    t0 = time.perf_counter()
    matches = [lib.match_image(img) for img in images]
    ms = 1e3 * (time.perf_counter() - t0) / len(rows)  # analysis + match per image, files already read
    split = np.array([cov.split(r.label, r.extra) for r in rows], dtype=object)
    ok = np.array([not m.unknown and m.label == r.label for m, r in zip(matches, rows, strict=True)])
    unknown = np.array([m.unknown for m in matches])
    res = {"entries": len(lib.entries), "n": len(rows), "recognition_rate": _rate(ok),
           "unknown_rate": _rate(unknown),
           "match_image_ms": round(ms, 3), "splits": {}}
    for name in SPLITS:
        sel = split == name
        if sel.any():
            res["splits"][name] = {"n": int(sel.sum()), "recognition_rate": _rate(ok[sel]),
                                   "unknown_rate": _rate(unknown[sel])}
    if features == "multi-hu":
        res["estimate"] = estimate_quality(rows, matches, ok, split)
    return res


def estimate_quality(rows, matches, ok, split) -> dict:
    """Pointing-error estimate against the manifests' truth (degrees), lamp geometry only."""
    truth = np.array([(r.az_deg, r.el_deg) for r in rows], dtype=float)
    est = np.array([m.error_deg if m.error_deg else (np.nan, np.nan) for m in matches], dtype=float)
    conf = np.array([m.confidence for m in matches])
    lamp = split != "held-out-geometry"
    good = ok & lamp & np.all(np.isfinite(est), axis=1)
    sure = lamp & (conf >= CONFIDENT)
    after = truth[sure] - est[sure]  # residual beam error once the coarse correction -est is applied

    def rms(a: np.ndarray) -> float:
        return round(float(np.sqrt(np.mean(np.sum(a**2, axis=1)))), 4) if a.size else float("nan")

    return {"rms_error_of_estimate_deg": rms(truth[good] - est[good]),
            "rms_true_error_deg": rms(truth[good]),
            "confident_share": _rate(sure[lamp]), "confident_precision": _rate(ok[sure]),
            "rms_before_coarse_deg": rms(truth[sure]), "rms_after_coarse_deg": rms(after)}


def independent(seeds: list[int], views: int) -> dict:
    """Recognition on the independent error set: CLI default and paper variant, and ablations."""
    import subprocess
    import sys

    from independent_spots import write_set

    import controller.recognition.library as library

    def cli(*args: str) -> dict:
        r = subprocess.run([sys.executable, "-m", "controller.cli", *args, "--json"], capture_output=True,
                           text=True, check=True)
        return json.loads(r.stdout)

    def by_effective_magnitude(out: Path) -> dict:
        # The renderer scales the aperture image and the source disc together with the spot size,
        # so a view is its case at magnitude m / spot, zoomed: the rate inside/outside the library's range.
        lib = build_library_from_manifest(out / "library.csv", "multi-hu")
        rows = read_manifest(out / "test.csv")
        ms = [lib.match_image(read_image(r.image)) for r in rows]
        ok = np.array([not m.unknown and m.label == r.label for m, r in zip(ms, rows, strict=True)])
        eff = np.array([float(r.extra["magnitude"]) / float(r.extra["spot"]) for r in rows])
        inside = (eff >= min(THREE)) & (eff <= max(THREE))
        return {"inside": {"n": int(inside.sum()), "recognition_rate": _rate(ok[inside])},
                "outside": {"n": int((~inside).sum()), "recognition_rate": _rate(ok[~inside])}}

    def api(out: Path, interpolate: bool, blur: bool) -> dict:
        saved = library.AUGMENT_BLUR
        library.AUGMENT_BLUR = saved if blur else ()
        try:
            lib = build_library_from_manifest(out / "library.csv", "multi-hu")
        finally:
            library.AUGMENT_BLUR = saved
        lib.interpolate = interpolate
        rows = read_manifest(out / "test.csv")
        ms = [lib.match_image(read_image(r.image)) for r in rows]
        ok = np.array([not m.unknown and m.label == r.label for m, r in zip(ms, rows, strict=True)])
        return {"recognition_rate": _rate(ok), "unknown_rate": _rate(np.array([m.unknown for m in ms]))}

    res: dict = {"views_per_case": views, "seeds": {}}
    for seed in seeds:
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp)
            write_set(out, seed=seed, views=views)
            r: dict = {}
            paper = ("--features", "hu", "--whiten", "no")
            kinds = (("multi-hu (default)", ()), ("blur-hu", ("--features", "blur-hu")),
                     ("multi-blur-hu", ("--features", "multi-blur-hu")), ("hu raw (paper)", paper))
            for name, extra in kinds:
                cli("library", "build", str(out / "library.csv"), "--out", str(out / "lib.yaml"), *extra)
                c = cli("report", "confusion", "--library", str(out / "lib.yaml"),
                        "--test", str(out / "test.csv"), "--out", str(out / "rep"))
                r[name] = {"recognition_rate": round(c["recognition_rate"], 2),
                           "unknown_rate": round(100 * c["unknown_rate"], 2),
                           "recall": {k: v["recall"] for k, v in c["per_class"].items()}}
            r["multi-hu, no interpolation"] = api(out, False, True)
            r["multi-hu, no blur views"] = api(out, True, False)
            r["multi-hu, neither (before #14 work)"] = api(out, False, False)
            r["multi-hu by effective magnitude m/spot"] = by_effective_magnitude(out)
            res["seeds"][seed] = r
    return res


def campaign(seed: int, threshold: float, heliostats: int) -> dict:
    """The demo with the coarse correction at ``threshold`` and its centroid-only twin (same seed)."""
    import subprocess
    import sys

    import yaml

    with tempfile.TemporaryDirectory() as tmp:
        data = yaml.safe_load(CONFIG.read_text(encoding="utf-8"))
        data["calibration"]["coarse_correction"] = threshold
        cfg = Path(tmp) / "config.yaml"
        cfg.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
        t0 = time.perf_counter()
        r = subprocess.run([sys.executable, "-m", "controller.cli", "demo", "--config", str(cfg),
                            "--seed", str(seed), "--heliostats", str(heliostats), "--nights", "0",
                            "--out", str(Path(tmp) / "out"), "--json"],
                           capture_output=True, text=True, check=False)
        if not r.stdout.strip():
            raise SystemExit(f"demo failed (exit {r.returncode}): {r.stderr.strip()[-2000:]}")
        d = json.loads(r.stdout)
    c = d["coarse_correction"]
    return {"seed": seed, "heliostats": heliostats, "threshold": threshold, "applied": c["applied"],
            "iterations_mean": c["iterations_mean"],
            "iterations_centroid_only_mean": c["iterations_centroid_only_mean"],
            "iterations_ratio": (c["iterations_mean"] / c["iterations_centroid_only_mean"]
                                 if c["iterations_centroid_only_mean"] else None),
            "iterations_mean_runs_with_coarse": c["iterations_mean_runs_with_coarse"],
            "error_after_mrad": d["error_after_mrad"],
            "error_after_centroid_only_mrad": c.get("error_after_centroid_only_mrad"),
            "calibrated": d["calibrated"], "wall_s": round(time.perf_counter() - t0, 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--dir", default=None, help="keep/reuse the rendered error set here")
    ap.add_argument("--campaign", action="store_true", help="coarse correction in the loop (see above)")
    ap.add_argument("--threshold", type=float, default=0.5, help="--campaign: calibration.coarse_correction")
    ap.add_argument("--heliostats", type=int, default=12, help="--campaign: heliostats of the demo")
    ap.add_argument("--independent", action="store_true", help="independent renderer's set (see above)")
    ap.add_argument("--seeds", default="1,2,3", help="--independent: seeds of the sets")
    args = ap.parse_args()
    if args.independent:
        print(json.dumps(independent([int(v) for v in args.seeds.split(",")], 24)))
        return
    if args.campaign:
        print(json.dumps(campaign(args.seed, args.threshold, args.heliostats)))
        return
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.dir) if args.dir else Path(tmp)
        t0 = time.perf_counter()
        if not (out / "test.csv").is_file():
            render(out, args.seed, args.views)
        render_s = time.perf_counter() - t0
        result = {"seed": args.seed, "views": args.views, "library_heliostats": list(LIBRARY),
                  "render_s": round(render_s, 1),
                  "variants": {name: score(out, *v) for name, v in VARIANTS.items()}}
    print(json.dumps(result))


if __name__ == "__main__":
    main()
