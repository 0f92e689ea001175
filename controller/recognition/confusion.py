"""Confusion matrix, recall and false-negative rate of error-case recognition.

Rows are the true class and columns the predicted class, both in ``labels`` order. A query
reported as unknown is a miss (a false negative of its true class) and appears in no column.
Overall: TP = trace, FN = all other test views (wrong label or unknown),
recall = TP / (TP + FN), FNR = 1 - recall, recognition rate = 100 x recall (in percent),
as in the paper's Table 4 (TP 79, FN 5 -> recall 0.94, FNR 0.06, 94.0476 %).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

UNKNOWN = "unknown"


@dataclass(frozen=True)
class Confusion:
    labels: list[str]
    matrix: np.ndarray  # (k, k) int, rows true, cols predicted
    unknown: np.ndarray  # (k,) int, unknown predictions per true class

    @property
    def tp(self) -> int:
        return int(np.trace(self.matrix))

    @property
    def n(self) -> int:
        return int(self.matrix.sum() + self.unknown.sum())

    @property
    def fn(self) -> int:
        return self.n - self.tp

    @property
    def recall(self) -> float:
        return self.tp / self.n if self.n else float("nan")

    @property
    def fnr(self) -> float:
        return 1.0 - self.recall

    @property
    def recognition_rate(self) -> float:
        """Percent of test views recognised as their true case."""
        return 100.0 * self.recall

    @property
    def unknown_rate(self) -> float:
        """Fraction of test views rejected as unknown."""
        return float(self.unknown.sum()) / self.n if self.n else float("nan")

    def per_class(self) -> dict[str, dict]:
        out = {}
        for i, lab in enumerate(self.labels):
            n = int(self.matrix[i].sum() + self.unknown[i])
            tp = int(self.matrix[i, i])
            out[lab] = {"n": n, "tp": tp, "fn": n - tp, "unknown": int(self.unknown[i]),
                        "recall": tp / n if n else None, "fnr": (n - tp) / n if n else None}
        return out

    def as_dict(self) -> dict:
        """The ``heliocal report confusion`` JSON contract (plus tp/fn/n totals)."""
        return {"labels": self.labels, "matrix": self.matrix.tolist(), "recall": self.recall, "fnr": self.fnr,
                "recognition_rate": self.recognition_rate, "per_class": self.per_class(),
                "tp": self.tp, "fn": self.fn, "n": self.n, "unknown": int(self.unknown.sum()),
                "unknown_rate": self.unknown_rate}


def confusion(true: list[str], predicted: list[str], labels: list[str] | None = None) -> Confusion:
    """Tally predictions (``"unknown"`` allowed) against true labels.

    ``labels`` fixes the order; by default the true labels in order of first appearance,
    followed by predicted labels that never occur as truth.
    """
    if len(true) != len(predicted):
        raise ValueError("true and predicted must have the same length")
    if labels is None:
        labels = list(dict.fromkeys(list(true) + [p for p in predicted if p != UNKNOWN]))
    else:
        labels = list(labels) + [t for t in dict.fromkeys(true) if t not in labels]
    index = {lab: i for i, lab in enumerate(labels)}
    k = len(labels)
    m = np.zeros((k, k), dtype=np.int64)
    unk = np.zeros(k, dtype=np.int64)
    for t, p in zip(true, predicted, strict=True):
        if p == UNKNOWN:
            unk[index[t]] += 1
        else:
            m[index[t], index[p]] += 1
    return Confusion(labels, m, unk)


MECHANISM_SEP = "+"


def mechanisms(label: str) -> tuple[str, ...]:
    """The mechanisms a case label names: ``"wind-load+gear-backlash"`` -> both; unknown -> none."""
    return () if label == UNKNOWN else tuple(label.split(MECHANISM_SEP))


def mechanism_recall(true: list[str], predicted: list[str]) -> dict[str, dict]:
    """Recognition by mechanism, for libraries with combined cases (labels ``"a+b"``): per
    mechanism M, ``n`` = test views whose true case involves M, ``found`` = those whose predicted
    case involves M too, ``recall`` = found / n, and ``exact`` = those recognised as their whole
    case. A view of ``a+b`` called ``a`` finds a and misses b; called ``a+c`` it finds a and
    counts c nowhere (a false mechanism is not a recall matter)."""
    out: dict[str, dict] = {}
    for t, p in zip(true, predicted, strict=True):
        said = set(mechanisms(p))
        for m in mechanisms(t):
            row = out.setdefault(m, {"n": 0, "found": 0, "exact": 0})
            row["n"] += 1
            row["found"] += m in said
            row["exact"] += p == t
    for row in out.values():
        row["recall"] = row["found"] / row["n"]
    return out
