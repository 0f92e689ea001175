"""A Ctrl-C (SIGTERM) that lands inside a write leaves the database as if the write had either
happened whole or not at all, and the next write goes through.

Python raises ``KeyboardInterrupt`` where the main thread next checks for signals: on entering
a Python function (or at a loop's back edge). A trace function raises it at each such point of
one ``record_run`` in turn, and at each line of the transaction itself, deterministically: the
ending the interrupted night records next (``finish_campaign``) must not meet a transaction the
interrupt left open (``cannot start a transaction within a transaction``, exit 2)."""

from __future__ import annotations

import gc
import sys

import pytest

from controller.storage import db as db_module
from controller.storage.db import CampaignStore
from tests.storage.test_db import _open, _run

TX_FILE = db_module.__file__


def _interrupt_at(k: int):
    """A trace function raising KeyboardInterrupt at the ``k``-th function entry (or line of
    :mod:`controller.storage.db`), counting from 1."""
    seen = [0]

    def tracer(frame, event, arg):
        if event == "call" or (event == "line" and frame.f_code.co_filename == TX_FILE):
            seen[0] += 1
            if seen[0] == k:
                raise KeyboardInterrupt
        return tracer
    return tracer


def _write(store: CampaignStore, cid: int, hid: str, k: int) -> bool:
    """``record_run`` of ``hid`` interrupted at point ``k``; whether the interrupt landed. The
    collector is off meanwhile: an exception raised in a collection's callback (Hypothesis
    registers one once a property test has run in the worker) is printed and dropped, and the
    write would then pass point ``k`` uninterrupted."""
    collecting = gc.isenabled()
    gc.disable()
    sys.settrace(_interrupt_at(k))
    try:
        store.record_run(cid, _run(hid))
    except KeyboardInterrupt:
        return True
    finally:
        sys.settrace(None)
        if collecting:
            gc.enable()
    return False


def test_an_interrupt_anywhere_in_a_write_leaves_it_whole_or_absent(tmp_path):
    with CampaignStore(tmp_path / "c.db") as store:
        cid, _ = _open(store)
        k = 0
        while True:  # point k = 1, 2, … until the write passes every point and completes
            k += 1
            hid = f"H{k}"
            landed = _write(store, cid, hid, k)
            # What the interrupted night writes next:
            store.finish_campaign(cid, "interrupted", "interrupted by the operator")
            assert not store._db.in_transaction, f"point {k}"
            runs = store._db.execute("SELECT id FROM heliostat_runs WHERE heliostat_id=?", (hid,)).fetchall()
            if runs:
                n = store._db.execute("SELECT COUNT(*) FROM measurements WHERE run_id=?",
                                      (runs[0][0],)).fetchone()[0]
                assert n == 2, f"point {k}: half a run recorded"
            if not landed:
                assert runs, "the write that was not interrupted is recorded"
                break
        assert k > 50  # the write passed many points where a signal can land
        assert store.campaign(cid).status == "interrupted"


def test_a_body_that_fails_rolls_back_and_the_store_goes_on(tmp_path):
    with CampaignStore(tmp_path / "c.db") as store:
        cid, _ = _open(store)
        with pytest.raises(ValueError), store.tx() as db:
            db.execute("UPDATE campaigns SET cause='x' WHERE id=?", (cid,))
            raise ValueError("the body failed")
        assert store.campaign(cid).cause is None and not store._db.in_transaction
        store.record_run(cid, _run("H1"))
        assert store.count("heliostat_runs") == 1
