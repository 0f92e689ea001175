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
For the ``multi-lobe-hu`` / ``multi-hu`` variants it also reports the magnitude estimate: RMS error of the
interpolated beam pointing error against the truth over correctly recognised views, and the
share and precision of views with confidence >= 0.5 (where a coarse correction would be applied)
with the RMS pointing error before and after applying it. ``--dir`` keeps the rendered set (and
reuses it on the next run).

``--independent [--seeds 1,2,3]``: instead, the two independent error sets, rendered apart from
``simplant.optics`` and from each other: :mod:`independent_spots` (paraxial mirror, spot size =
zoom of aperture image and source disc) and :mod:`facet_spots` (3 x 3 rigid facets, limb-darkened
sun, slope errors, spot size = blur). In both, magnitude 0.5-1.5 and spot size x0.7-1.4 vary in
the test views (24 per case) and the library holds 3 magnitudes per case. Scored through the CLI
contract (``heliocal library build`` default and ``--features multi-hu``, ``blur-hu``,
``multi-blur-hu``, ``hu --whiten no``; ``heliocal report confusion --json``), plus ablations of
the default through the Python API (no interpolation between magnitudes, no widening, no blur
views, the entries' covariance added to the whitening as before), the default's rate by nuisance
(m / spot inside or outside the library's 0.5-1.5 for the first renderer, spot size for the
second), and the price of the widening: each case left out of the library in turn, how many of
its views are still rejected as unknown, with and without widening.
JSON: ``renderers.{independent_spots,facet_spots}.seeds.{seed}`` (and ``seeds`` = the first).

``--combined [--seed S] [--views 6] [--dir DIR]``: instead, combined errors (:func:`combined`).

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
    "multi-lobe-hu whitened (default), 12 heliostats x 9 sizes": ("multi-lobe-hu", None, SIZES, LIBRARY),
    "multi-lobe-hu whitened (default), 6 heliostats x 9 sizes": ("multi-lobe-hu", None, SIZES, SIX),
    "multi-lobe-hu whitened (default), 6 heliostats x 3 sizes": ("multi-lobe-hu", None, THREE, SIX),
    "multi-hu whitened, 12 heliostats x 9 sizes": ("multi-hu", None, SIZES, LIBRARY),
    "multi-hu whitened, 6 heliostats x 3 sizes": ("multi-hu", None, THREE, SIX),
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
    def keep(r) -> bool:
        return float(r.extra["magnitude"]) in sizes and r.extra["heliostat"] in heliostats

    return subset_manifest(out, f"library-{len(heliostats)}x{len(sizes)}.csv", keep)


def subset_manifest(out: Path, name: str, keep) -> Path:
    """``out/name``: the rows of ``out/library.csv`` for which ``keep(row)`` holds."""
    rows = [r for r in read_manifest(out / "library.csv") if keep(r)]
    path = out / name
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
    if features in ("multi-hu", "multi-lobe-hu"):
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
    """Recognition on the two independent error sets: CLI default and other kinds, and ablations."""
    import subprocess
    import sys

    import facet_spots
    import independent_spots

    import controller.recognition.library as library

    def cli(*args: str) -> dict:
        r = subprocess.run([sys.executable, "-m", "controller.cli", *args, "--json"], capture_output=True,
                           text=True, check=True)
        return json.loads(r.stdout)

    def scored(out: Path, lib) -> tuple[list, np.ndarray]:
        rows = read_manifest(out / "test.csv")
        ms = [lib.match_image(read_image(r.image)) for r in rows]
        return rows, np.array([not m.unknown and m.label == r.label for m, r in zip(ms, rows, strict=True)])

    def by_nuisance(out: Path, effective: bool) -> dict:
        # independent_spots scales the aperture image and the source disc together with the spot
        # size, so a view is its case at magnitude m / spot, zoomed: the rate inside/outside the
        # library's range. facet_spots blurs instead: the rate by spot size.
        rows, ok = scored(out, build_library_from_manifest(out / "library.csv", "multi-lobe-hu"))
        m = np.array([float(r.extra["magnitude"]) for r in rows])
        spot = np.array([float(r.extra["spot"]) for r in rows])
        if effective:
            inside = (m / spot >= min(THREE)) & (m / spot <= max(THREE))
            groups = {"m/spot inside 0.5-1.5": inside, "m/spot outside": ~inside}
        else:
            groups = {"spot < 1": spot < 1.0, "spot >= 1": spot >= 1.0}
        return {k: {"n": int(sel.sum()), "recognition_rate": _rate(ok[sel])} for k, sel in groups.items()}

    def entries_in_whitening(x, spread, floor=1e-6):
        # The whitening before this work: covariance of the entries (how the cases differ) added
        # to the within-case spread (the ablation "entries' covariance in the whitening").
        k = x.shape[1]
        dev = spread.deviations
        c = np.cov(np.asarray(x, dtype=np.float64).T, bias=True).reshape(k, k) + dev.T @ dev / dev.shape[0]
        w, v = np.linalg.eigh(c)
        w = np.maximum(w, floor * w.max())
        return (v / np.sqrt(w)) @ v.T

    def api(out: Path, kind: str, interpolate: bool = True, blur: bool = True,
            total_cov: bool = False, widen: bool = True) -> dict:
        saved = library.AUGMENT_BLUR, library.whitening
        library.AUGMENT_BLUR = saved[0] if blur else ()
        library.whitening = entries_in_whitening if total_cov else saved[1]
        try:
            lib = build_library_from_manifest(out / "library.csv", kind)
        finally:
            library.AUGMENT_BLUR, library.whitening = saved
        lib.interpolate = interpolate
        lib.widen = lib.widen if widen else ()
        rows, ok = scored(out, lib)
        return {"recognition_rate": _rate(ok)}

    def novel(out: Path, cases) -> dict:
        # Each case left out of the library in turn: how many of its views the default still
        # rejects as unknown, with and without widening (the price of the widening).
        rows = read_manifest(out / "library.csv")
        test = read_manifest(out / "test.csv")
        images = {r.image: read_image(r.image) for r in rows}
        views = [read_image(r.image) for r in test]
        kept = {"n": 0, "rejected": 0, "rejected_without_widening": 0}
        for case in cases:
            lib_rows = [r for r in rows if r.label != case]
            lib = library.build_library([images[r.image] for r in lib_rows], [r.label for r in lib_rows],
                                        kind="multi-lobe-hu")
            mine = [v for v, r in zip(views, test, strict=True) if r.label == case]
            kept["n"] += len(mine)
            kept["rejected"] += sum(lib.match_image(v).unknown for v in mine)
            lib.widen = ()
            kept["rejected_without_widening"] += sum(lib.match_image(v).unknown for v in mine)
        return kept

    paper = ("--features", "hu", "--whiten", "no")
    kinds = (("multi-lobe-hu (default)", ()), ("multi-hu", ("--features", "multi-hu")),
             ("blur-hu", ("--features", "blur-hu")), ("multi-blur-hu", ("--features", "multi-blur-hu")),
             ("hu raw (paper)", paper))
    renderers = {"independent_spots": (independent_spots, True), "facet_spots": (facet_spots, False)}
    res: dict = {"views_per_case": views, "renderers": {}}
    for rname, (module, effective) in renderers.items():
        per_seed: dict = {}
        for seed in seeds:
            with tempfile.TemporaryDirectory() as tmp:
                out = Path(tmp)
                module.write_set(out, seed=seed, views=views)
                r: dict = {}
                for name, extra in kinds:
                    cli("library", "build", str(out / "library.csv"), "--out", str(out / "lib.yaml"), *extra)
                    c = cli("report", "confusion", "--library", str(out / "lib.yaml"),
                            "--test", str(out / "test.csv"), "--out", str(out / "rep"))
                    r[name] = {"recognition_rate": round(c["recognition_rate"], 2),
                               "unknown_rate": round(100 * c["unknown_rate"], 2),
                               "recall": {k: v["recall"] for k, v in c["per_class"].items()}}
                r["default, no interpolation"] = api(out, "multi-lobe-hu", interpolate=False)
                r["default, no widening"] = api(out, "multi-lobe-hu", widen=False)
                r["default, no blur views"] = api(out, "multi-lobe-hu", blur=False)
                r["default, entries' covariance in the whitening"] = api(out, "multi-lobe-hu", total_cov=True)
                r["multi-hu, entries' covariance in the whitening (before)"] = api(out, "multi-hu",
                                                                                    total_cov=True)
                r["default by nuisance"] = by_nuisance(out, effective)
                r["case left out of the library: views rejected as unknown"] = novel(out, module.CASES)
                per_seed[seed] = r
        default = [v["multi-lobe-hu (default)"]["recognition_rate"] for v in per_seed.values()]
        res["renderers"][rname] = {"seeds": per_seed,
                                   "default_mean_recognition_rate": round(float(np.mean(default)), 2),
                                   "default_min_recognition_rate": min(default)}
    res["seeds"] = res["renderers"]["independent_spots"]["seeds"]  # the key of earlier runs: first renderer
    return res


COMBINED_TEST = ("H02", "H10", "H17")


def combined(seed: int, views: int, out: Path) -> dict:
    """Combined errors (two mechanisms at once) as cases of their own: the 6 cases and the 10
    pairs of the five that change the shape (``write_errorset(combined=True)``), library on six
    heliostats at sizes 0.5, 1, 1.5, test views on three other heliostats (sizes 0.5-1.5).
    Default library, scored per kind of case and by mechanism
    (:func:`controller.recognition.confusion.mechanism_recall`); the peer is the library of
    the six single cases only, scored by mechanism on the same pair views."""
    from controller.recognition.confusion import mechanism_recall

    cfg = load_config(CONFIG)
    if not (out / "test.csv").is_file():
        write_errorset(out, [scene_from_config(cfg, h) for h in SIX], seed=seed, views=views,
                       magnitudes=THREE, test_scenes=[scene_from_config(cfg, h) for h in COMBINED_TEST],
                       test_magnitude_range=(0.5, 1.5), combined=True)
    rows = read_manifest(out / "test.csv")
    images = [read_image(r.image) for r in rows]
    true = [r.label for r in rows]
    pair = np.array(["+" in t for t in true])
    res: dict = {"seed": seed, "views": views, "library_heliostats": list(SIX),
                 "test_heliostats": list(COMBINED_TEST)}
    path = subset_manifest(out, "library-singles.csv", lambda r: "+" not in r.label)
    for name, manifest in (("with pairs", out / "library.csv"), ("singles only (peer)", path)):
        lib = build_library_from_manifest(manifest, "multi-lobe-hu")
        pred = []
        for img in images:
            m = lib.match_image(img)
            pred.append("unknown" if m.unknown else m.label)
        ok = np.array([p == t for p, t in zip(pred, true, strict=True)])
        on_pairs = mechanism_recall([t for t, q in zip(true, pair, strict=True) if q],
                                    [p for p, q in zip(pred, pair, strict=True) if q])
        found = sum(r["found"] for r in on_pairs.values()) / max(1, sum(r["n"] for r in on_pairs.values()))
        both = np.mean([set(t.split("+")) <= set(p.split("+"))
                        for t, p, q in zip(true, pred, pair, strict=True) if q])
        res[name] = {"entries": len(lib.entries), "recognition_rate": _rate(ok),
                     "single_cases": _rate(ok[~pair]), "pair_cases": _rate(ok[pair]),
                     "unknown_rate": _rate(np.array([p == "unknown" for p in pred])),
                     "pair_views_mechanisms_found": round(100.0 * found, 2),
                     "pair_views_both_found": round(100.0 * float(both), 2),
                     "mechanisms": {k: round(100.0 * v["recall"], 1) for k, v in
                                    mechanism_recall(true, pred).items()}}
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
    ap.add_argument("--combined", action="store_true", help="combined errors as own cases (see above)")
    args = ap.parse_args()
    if args.combined:
        with tempfile.TemporaryDirectory() as tmp:
            print(json.dumps(combined(args.seed, args.views, Path(args.dir) if args.dir else Path(tmp))))
        return
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
