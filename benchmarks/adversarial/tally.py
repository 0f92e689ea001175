"""The count kept per category by ``bench_adversarial.py`` and its category modules.

Each other module of this folder holds categories of its own: a function
``categories(folder: Path) -> dict[str, dict]`` (``folder``: a scratch folder that is removed
afterwards) returning, per category name, :meth:`Tally.report` (or any JSON object; those with
``"tried"`` count in the total).
"""

from __future__ import annotations

import time
import tracemalloc

from controller.errors import InputError


class Tally:
    def __init__(self) -> None:
        self.tried = self.refused = 0
        self.worst_ms = self.worst_mb = 0.0
        self.failures: list[str] = []

    def case(self, name: str, fn, refused) -> None:
        """Run ``fn``; ``refused(exc_or_result)`` says whether it ended as it must."""
        self.tried += 1
        tracemalloc.start()
        t0 = time.perf_counter()
        try:
            outcome = fn()
        except BaseException as exc:  # noqa: BLE001 - judged below
            outcome = exc
        ms = (time.perf_counter() - t0) * 1e3
        peak = tracemalloc.get_traced_memory()[1] / 1e6
        tracemalloc.stop()
        self.worst_ms, self.worst_mb = max(self.worst_ms, ms), max(self.worst_mb, peak)
        if refused(outcome):
            self.refused += 1
        else:
            self.failures.append(f"{name}: {outcome!r}"[:200])

    def report(self) -> dict:
        return {"tried": self.tried, "refused_cleanly": self.refused, "worst_ms": round(self.worst_ms, 2),
                "worst_peak_mb": round(self.worst_mb, 3), "failures": self.failures[:5]}


def _input_error(outcome) -> bool:
    return isinstance(outcome, InputError) and "\n" not in str(outcome)
