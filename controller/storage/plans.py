"""The ``plan`` table: what the nightly planner chose for each heliostat and why.

One row per planned measurement (night name, heliostat, rank), with the geometry (lamp, target,
aim point and grid cell, the steps it expected), the expected gain and the predicted daytime RMS
before and after it. A resumed night runs the plan stored for it, not a new one.
"""

from __future__ import annotations

from controller.calibration.night.planner import Geometry, PlanItem
from controller.calibration.records import utc_now
from controller.storage.db import CampaignStore


def record_plan(store: CampaignStore, items: list[PlanItem]) -> None:
    """Store a night's plan in one transaction (an item already stored is left as it was)."""
    with store.tx() as db:
        for it in items:
            g = it.geometry
            db.execute(
                "INSERT OR IGNORE INTO plan (night, heliostat_id, rank, strategy, lamp, aim_e, aim_n, aim_u, "
                "cell_row, cell_col, az_steps, el_steps, expected_gain, predicted_before_mrad, "
                "predicted_after_mrad, created_utc, target) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                (it.night, it.heliostat_id, it.rank, it.strategy, g.lamp, *g.aim_enu, *g.cell, *g.steps,
                 it.gain, it.predicted_before_mrad, it.predicted_after_mrad, utc_now(), g.target))


def load_plan(store: CampaignStore, night: str | None = None) -> list[PlanItem]:
    """The stored plan of ``night`` (every night when None), by night, heliostat and rank."""
    if night is None:
        rows = store.query("SELECT * FROM plan ORDER BY id")
    else:
        rows = store.query("SELECT * FROM plan WHERE night=? ORDER BY id", (night,))
    return [PlanItem(r["heliostat_id"], r["night"],
                     Geometry(r["lamp"], (r["aim_e"], r["aim_n"], r["aim_u"]), (r["cell_row"], r["cell_col"]),
                              (r["az_steps"], r["el_steps"]), r["target"]),
                     r["rank"], r["expected_gain"], r["predicted_before_mrad"], r["predicted_after_mrad"],
                     r["strategy"]) for r in rows]
