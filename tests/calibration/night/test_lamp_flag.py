"""A heliostat that fails under one lamp night after night at a different aim point each night
(the demo's H01 under the west lamp: its spot clipped at the view's edge wherever it aims) has
the whole lamp flagged: listed, not planned again for it, cleared with the command
(docs/nights.md, "Flagged geometries")."""

from __future__ import annotations

import json
from pathlib import Path

from controller.calibration.night.passes import flagged_keys
from controller.calibration.night.planner import plan_field
from controller.commands.field import open_store
from controller.config import load_config
from controller.storage.geometry_flags import flagged, record_failures
from tests.calibration.conftest import calibrated_record
from tests.conftest import run_cli

ROOT = Path(__file__).resolve().parents[3]
CLIPPED = "BeamNotFound: beam spot clipped by the right edge of the camera view after 2 corrections"


def _fail(store, night: str, hid: str, lamp: str, target: str, cell: tuple[int, int]) -> None:
    record_failures(store, night, [{"heliostat": hid, "lamp": lamp, "target": target, "cell": cell,
                                    "status": "failed", "cause": CLIPPED}])


def test_a_lamp_failing_at_a_new_aim_point_each_night_is_flagged_whole(tmp_path):
    cfg = load_config(ROOT / "configs" / "demo.yaml")
    db = tmp_path / "c.db"
    store = open_store(db)
    try:
        _fail(store, "n/night-1", "H01", "lamp-west", "tower-lower", (0, 1))
        assert flagged(store) == []  # one night: nothing yet
        _fail(store, "n/night-2", "H01", "lamp-west", "tower-target", (1, 1))
        _fail(store, "n/night-2", "H02", "lamp-west", "tower-lower", (0, 1))  # another heliostat, once
        flags = flagged(store)
        assert [(g["heliostat"], g["lamp"], g["target"], g["cell"], g["nights"]) for g in flags] == [
            ("H01", "lamp-west", None, None, ["n/night-1", "n/night-2"])]

        models = {h: calibrated_record(cfg, h) for h in ("H01", "H02")}
        before = plan_field(cfg, models, "n/night-3", workers=1)
        after = plan_field(cfg, models, "n/night-3", workers=1, flagged=flagged_keys(flags))
        def lamps(plan, hid: str) -> set[str]:
            return {it.geometry.lamp for it in plan.items if it.heliostat_id == hid}

        assert "lamp-west" in lamps(before, "H01")  # planned under the west lamp before the flag,
        assert "lamp-west" not in lamps(after, "H01")  # not after it,
        assert "lamp-west" in lamps(after, "H02")  # and still for the heliostat that failed once
    finally:
        store.close()

    code, out, err = run_cli(["campaign", "flags", "--db", str(db)])
    assert code == 0 and "H01 under lamp-west on every target and aim cell" in out, err
    code, out, err = run_cli(["campaign", "flags", "--db", str(db), "--clear", "H01", "--json"])
    assert code == 0 and json.loads(out)["cleared"][0]["target"] is None, err
    assert json.loads(run_cli(["campaign", "flags", "--db", str(db), "--json"])[1])["flagged"] == []
