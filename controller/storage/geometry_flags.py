"""The ``geometry_failures`` table: planned geometries that were tried and gave no measurement,
and the flags they raise (docs/nights.md, "Flagged geometries").

A planned night records, per pass, each heliostat whose look at its geometry (lamp, target,
aim grid cell) failed (:func:`controller.calibration.campaign.outcome.looked_and_failed`: no beam, a
spot clipped at the view's edge). A geometry that failed on :data:`FLAG_NIGHTS` nights is
*flagged*: the planner does not plan it again, the report and the console show it, until it is
cleared (:func:`clear_flags`, ``heliocal campaign flags --clear``), which keeps the rows (with
the time they were cleared) as the history.

A heliostat whose looks under one lamp failed on :data:`FLAG_NIGHTS` nights at geometries not
flagged each on their own (a different target or aim point each night) has that whole lamp
flagged (``target`` and ``cell`` None: every geometry under it): a spot clipped at the view's
edge under a lamp at one aim point is, the next night, as clipped at the next one the planner
picks (the demo's H01 under the west lamp).
"""

from __future__ import annotations

from controller.calibration.records import utc_now
from controller.errors import InputError
from controller.storage.checks import has_table
from controller.storage.db import CampaignStore

FLAG_NIGHTS = 2  # nights a geometry failed on before it is flagged


def record_failures(store: CampaignStore, night: str, failures: list[dict]) -> None:
    """Record the geometries that failed in night ``night``: dicts with ``heliostat``, ``lamp``,
    ``target``, ``cell`` (row, col), ``status`` and ``cause``; once per night and geometry."""
    now = utc_now()
    with store.tx() as db:
        db.executemany("INSERT OR IGNORE INTO geometry_failures (night, heliostat_id, lamp, target, "
                       "cell_row, cell_col, status, cause, recorded_utc) VALUES (?,?,?,?,?,?,?,?,?)",
                       [(night, f["heliostat"], f["lamp"], f["target"], *f["cell"], f["status"], f["cause"],
                         now) for f in failures])


def flagged(store: CampaignStore, ids: list[str] | None = None) -> list[dict]:
    """The flagged geometries (of heliostats ``ids``, or all), by heliostat: ``heliostat``,
    ``lamp``, ``target``, ``cell`` [row, col] (both None: the whole lamp, module docstring), the
    ``nights`` it failed on since it was last cleared and the last ``cause``."""
    if not has_table(store, "geometry_failures"):
        return []
    groups: dict[tuple, dict] = {}
    for r in store.query("SELECT * FROM geometry_failures WHERE cleared_utc IS NULL ORDER BY id"):
        key = (r["heliostat_id"], r["lamp"], r["target"], r["cell_row"], r["cell_col"])
        g = groups.setdefault(key, {"heliostat": key[0], "lamp": key[1], "target": key[2],
                                    "cell": [key[3], key[4]], "nights": [], "cause": None})
        g["nights"].append(r["night"])
        g["cause"] = r["cause"]
    single = [g for g in groups.values() if len(set(g["nights"])) >= FLAG_NIGHTS]
    # The whole lamp when its failures at geometries not flagged each on its own (a different
    # target or aim point each night) span FLAG_NIGHTS nights; one geometry failing again is that
    # geometry's flag, its neighbours may still work.
    lamps: dict[tuple, dict] = {}
    for g in groups.values():
        if len(set(g["nights"])) >= FLAG_NIGHTS:
            continue
        whole = lamps.setdefault((g["heliostat"], g["lamp"]), {"heliostat": g["heliostat"], "lamp": g["lamp"],
                                                               "target": None, "cell": None, "nights": [],
                                                               "cause": None})
        whole["nights"] = list(dict.fromkeys([*whole["nights"], *g["nights"]]))
        whole["cause"] = g["cause"]
    flags = [g for g in lamps.values() if len(g["nights"]) >= FLAG_NIGHTS] + single
    wanted = None if ids is None else set(ids)
    return sorted((g for g in flags if wanted is None or g["heliostat"] in wanted),
                  key=lambda g: (g["heliostat"], g["lamp"], g["target"] or "", g["cell"] or []))


def clear_flags(store: CampaignStore, heliostats: list[str] | None, lamp: str | None = None) -> list[dict]:
    """Clear the flags of ``heliostats`` (None: every heliostat), only those under ``lamp`` when
    given: their failures so far no longer count (kept, with the time they were cleared). The
    flags cleared; InputError naming what was asked when none matched (nothing is written)."""
    hit = [g for g in flagged(store, heliostats) if lamp is None or g["lamp"] == lamp]
    if not hit:
        what = ("any heliostat" if heliostats is None else ", ".join(heliostats)) + \
            (f" under lamp {lamp}" if lamp else "")
        shown = ", ".join(sorted({g["heliostat"] for g in flagged(store)})) or "none"
        raise InputError(f"{store.path}: no flagged geometry of {what} (flagged heliostats: {shown})")
    now = utc_now()
    with store.tx() as db:
        db.executemany("UPDATE geometry_failures SET cleared_utc=? WHERE cleared_utc IS NULL "
                       "AND heliostat_id=? AND lamp=? AND target=? AND cell_row=? AND cell_col=?",
                       [(now, g["heliostat"], g["lamp"], g["target"], *g["cell"]) for g in hit
                        if g["target"] is not None])
        db.executemany("UPDATE geometry_failures SET cleared_utc=? WHERE cleared_utc IS NULL "
                       "AND heliostat_id=? AND lamp=?",
                       [(now, g["heliostat"], g["lamp"]) for g in hit if g["target"] is None])
    return hit
