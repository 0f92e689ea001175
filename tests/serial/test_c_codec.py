"""The C99 reference codec passes the same shared vectors as the Python codec."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

C_DIR = Path(__file__).resolve().parents[2] / "firmware_proto" / "c"
VECTORS = C_DIR.parent / "vectors" / "frames.json"


def _compiler() -> str | None:
    for cc in ("cc", "gcc", "clang"):
        if shutil.which(cc):
            return cc
    return None


def test_c_codec_against_shared_vectors(tmp_path, vectors):
    cc = _compiler()
    if cc is None:
        print("SKIP: no C compiler (cc, gcc or clang) on PATH")
        pytest.skip("no C compiler (cc, gcc or clang) on PATH; install gcc to run the C codec test")
    subprocess.run([sys.executable, str(C_DIR / "gen_vectors.py"), str(VECTORS), str(tmp_path / "vectors.h")],
                   check=True)
    exe = tmp_path / "test_vectors"
    build = subprocess.run(
        [cc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2", f"-I{C_DIR}", f"-I{tmp_path}",
         str(C_DIR / "hc_frame.c"), str(C_DIR / "test_vectors.c"), "-o", str(exe)],
        capture_output=True, text=True)
    assert build.returncode == 0, build.stderr
    run = subprocess.run([str(exe)], capture_output=True, text=True, timeout=30)
    print(run.stdout)
    assert run.returncode == 0, run.stdout
    n_valid, n_invalid = len(vectors["valid"]), len(vectors["invalid"])
    assert f"{n_valid} valid, {n_invalid} invalid vectors, 0 failures" in run.stdout
