"""The CLI keeps freed memory for the next array (controller.commands._heap): arrays of megabytes
allocated and freed in turn, as a render or an HDR merge does, stop costing the kernel page
faults. Run in a fresh interpreter: the thresholds are process-wide and cannot be unset."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

CHURN = """
import json, resource
import numpy as np
from controller.commands._heap import keep_freed_memory

def churn():
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(50):  # three 1.9 MB arrays per round, as a ray trace of 80,000 rays has
        a = np.ones((3, 80_000)); b = a * 2.0; c = b + a; del a, b, c
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0

churn()
before = churn()
kept = keep_freed_memory()
churn()
print(json.dumps({"kept": kept, "before": before, "after": churn()}))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="mallopt thresholds are glibc's (Linux)")
def test_freed_arrays_are_reused_without_page_faults():
    r = subprocess.run([sys.executable, "-c", CHURN], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    if not out["kept"]:
        pytest.skip(f"this C library refused the thresholds (not glibc?): {out}")
    assert out["before"] > 5_000, out  # the default thresholds give the heap back every round
    assert out["after"] < out["before"] / 20, out
