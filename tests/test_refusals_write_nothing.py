"""Every refusal of a command that writes outputs leaves its folder as it was (issue 45): exit 2,
one line, nothing new, nothing changed — outputs whose folder is missing or that exist as
something else, duplicate ids, numbers that are not ASCII, absurd record values
(tests/refusal_cases.py builds the cases per category)."""

from __future__ import annotations

import time

import pytest

from tests.refusal_cases import cases, make_folder, refused_cleanly, run, snapshot


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("refusals")
    return d, make_folder(d)


def test_every_refusal_leaves_the_folder_as_it_was(folder, scaled):
    d, v = folder
    failures, worst = [], 0.0
    for name, argv in cases(v):
        before = snapshot(d)
        t0 = time.perf_counter()
        code, out, err = run(argv)
        worst = max(worst, time.perf_counter() - t0)
        why = refused_cleanly(code, out, err, before, snapshot(d))
        if why:
            failures.append(f"{name}: {why}")
    assert not failures, "\n".join(failures)
    assert worst < scaled(10.0)
