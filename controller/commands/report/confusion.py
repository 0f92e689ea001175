"""``heliocal report confusion --library LIB.yaml --test MANIFEST --out DIR``: recognition report.

Matches every test image against the library and writes into DIR: ``confusion.csv`` (rows true,
columns predicted, plus an ``unknown`` column), ``confusion.md`` (like the paper's Table 4, with
TP, FN, recall and FNR under it), ``confusion.png`` (heatmap) and ``report.json``. ``--json``
prints ``{"labels", "matrix", "recall", "fnr", "recognition_rate" (percent), "per_class"}``
(plus ``tp``, ``fn``, ``n``, ``unknown``, ``unknown_rate``, ``features`` and ``splits``); an
unknown prediction counts as a miss.

Splits (:mod:`controller.recognition.splits`): when the test manifest has the columns
``heliostat,source,slant_m,magnitude`` and the library's entries carry them as params, every
test view is assigned to ``seen``, ``held-out-magnitude``, ``held-out-heliostat`` or
``held-out-geometry``, and ``splits`` maps each non-empty one to its own confusion (same keys);
confusion.md gets one Table-4 matrix per split.
"""

from __future__ import annotations

import argparse
import csv
import io
from pathlib import Path

from controller.commands.common import _plain, add_json_option, existing_file, output_dir, print_json
from controller.commands.images.library import progress
from controller.errors import InputError
from controller.io.images import read_image, write_atomic
from controller.io.json_files import dumps_json
from controller.recognition.confusion import (
    MECHANISM_SEP,
    UNKNOWN,
    Confusion,
    confusion,
    mechanism_recall,
)
from controller.recognition.library_io import load_library, read_manifest
from controller.recognition.splits import SPLITS, Coverage
from controller.reports.confusion_plot import plot_confusion


def register(subparsers) -> None:
    p = subparsers.add_parser("confusion", help="confusion matrix of error-case recognition",
                              description=__doc__.splitlines()[0])
    p.add_argument("--library", required=True, metavar="LIB.yaml",
                   help="library from 'heliocal library build'")
    p.add_argument("--test", required=True, metavar="MANIFEST", help="test manifest CSV image,label,...")
    p.add_argument("--out", required=True, metavar="DIR", help="report directory")
    add_json_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    lib = load_library(existing_file(args.library, "library"))
    rows = read_manifest(existing_file(args.test, "test manifest"))
    output_dir(args.out)
    true, pred, widened = [], [], 0
    coverage = Coverage.of(lib.entries)
    split_of = [coverage.split(row.label, row.extra) for row in rows]
    with progress("matching test views", not args.json) as update:
        for i, row in enumerate(rows):
            try:
                m = lib.match_image(read_image(row.image))
            except InputError as exc:
                raise InputError(f"{args.test}:{row.line}: {exc}") from None
            true.append(row.label)
            pred.append(UNKNOWN if m.unknown else m.label)
            widened += m.widened > 0
            update(i + 1, len(rows))
    labels = list(dict.fromkeys(lib.labels))
    conf = confusion(true, pred, labels)
    splits = {}
    for name in SPLITS:
        idx = [i for i, s in enumerate(split_of) if s == name]
        if idx:
            splits[name] = confusion([true[i] for i in idx], [pred[i] for i in idx], labels)
    report = conf.as_dict() | {"features": lib.features, "widened": widened,
                               "mechanisms": mechanism_recall(true, pred),
                               "splits": {k: c.as_dict() for k, c in splits.items()}}
    write_report(conf, report, Path(args.out), splits)
    if args.json:
        print_json(report)
    else:
        print(f"recognition rate {conf.recognition_rate:.4f} % (TP {conf.tp}, FN {conf.fn}, "
              f"recall {conf.recall:.4f}, FNR {conf.fnr:.4f}, unknown {100 * conf.unknown_rate:.1f} %, "
              f"{widened} matched once widened); report in {args.out}")
        for k, c in splits.items():
            print(f"  {k}: {c.recognition_rate:.2f} % of {c.n} (unknown {100 * c.unknown_rate:.1f} %)")
    return 0


def confusion_csv(conf: Confusion) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["true\\predicted", *conf.labels, UNKNOWN])
    for i, lab in enumerate(conf.labels):
        w.writerow([lab, *conf.matrix[i].tolist(), int(conf.unknown[i])])
    return buf.getvalue()


def _table(conf: Confusion) -> list[str]:
    head = "| true \\ predicted | " + " | ".join(conf.labels) + f" | {UNKNOWN} | TPR | FNR |"
    sep = "|---|" + "---:|" * (len(conf.labels) + 3)
    lines = [head, sep]
    per = conf.per_class()
    for i, lab in enumerate(conf.labels):
        cells = [f"**{v}**" if j == i else str(v) for j, v in enumerate(conf.matrix[i].tolist())]
        rec, fnr = per[lab]["recall"], per[lab]["fnr"]
        rates = f"{rec:.2f} | {fnr:.2f}" if rec is not None else "– | –"
        lines.append(f"| {lab} | " + " | ".join(cells) + f" | {int(conf.unknown[i])} | {rates} |")
    return lines + [
        "",
        "| TP | FN | Recall | FNR | Recognition rate | Unknown |",
        "|---:|---:|---:|---:|---:|---:|",
        f"| {conf.tp} | {conf.fn} | {conf.recall:.4f} | {conf.fnr:.4f} | {conf.recognition_rate:.4f} % "
        f"| {100 * conf.unknown_rate:.2f} % |",
        "",
    ]


def confusion_markdown(conf: Confusion, features: str, splits: dict[str, Confusion] | None = None) -> str:
    """Table 4 style: one row per true case, predicted cases as columns, totals underneath; then
    the same per split."""
    lines = [f"# Confusion matrix ({features} features)", "", *_table(conf)]
    for name, c in (splits or {}).items():
        lines += [f"## Split: {name} ({c.n} views)", "", *_table(c)]
    lines += ["Rows: true case; columns: predicted case. An unknown prediction counts as a false negative.",
              ""]
    return "\n".join(lines)


def write_report(conf: Confusion, report: dict, out: Path,
                 splits: dict[str, Confusion] | None = None) -> None:
    out.mkdir(parents=True, exist_ok=True)
    csv_text = confusion_csv(conf)
    md_text = confusion_markdown(conf, report.get("features", ""), splits) + _mechanism_table(report)
    json_text = dumps_json(_plain(report), indent=2) + "\n"
    plot_confusion(conf.matrix, conf.unknown, list(conf.labels), out / "confusion.png",
                   title=f"recognition rate {conf.recognition_rate:.2f} % ({report.get('features', '')})")
    write_atomic(out / "confusion.csv", lambda t: t.write_text(csv_text, encoding="utf-8"))
    write_atomic(out / "confusion.md", lambda t: t.write_text(md_text, encoding="utf-8"))
    write_atomic(out / "report.json", lambda t: t.write_text(json_text, encoding="utf-8"))


def _mechanism_table(report: dict) -> str:
    """Recall by mechanism when the library has combined cases (labels ``a+b``); else nothing."""
    rows = report.get("mechanisms") or {}
    if not any(MECHANISM_SEP in lab for lab in report.get("labels", [])):
        return ""
    lines = ["", "## By mechanism (combined cases count for each of theirs)", "",
             "| mechanism | views involving it | named in the prediction | recall | whole case right |",
             "|---|---:|---:|---:|---:|"]
    lines += [f"| {m} | {r['n']} | {r['found']} | {r['recall']:.3f} | {r['exact']} |"
              for m, r in rows.items()]
    return "\n".join(lines) + "\n"
