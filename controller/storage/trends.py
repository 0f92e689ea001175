"""Each heliostat's nights side by side: what the night report's trend plot and the console's
heliostat page show.

Per heliostat and night (by index): the geometries measured, the mean measured pointing error
of the night's first looks (a measurement's iteration 1: a planned night's one look per
geometry, the calibration night's first look before any correction; the reflected-beam angle
from the aim point, mrad) and, for a planned night (``night_heliostats``, schema v9), the
geometries planned and the daytime RMS the heliostat's model predicted after it (open loop,
mrad). A few queries for any number of heliostats.
"""

from __future__ import annotations

from controller.storage.db import CampaignStore
from controller.storage.nights import HELIOSTATS_SCHEMA, NightBook, night_of

CHUNK = 900  # ids per IN (...) query: under SQLite's oldest limit of 999 variables


def heliostat_trends(store: CampaignStore, ids: list[str]) -> dict[str, list[dict]]:
    """Per heliostat of ``ids``, its nights oldest first (module docstring): each
    ``{"night", "name", "kind", "planned", "measured", "first_look_error_mrad",
    "predicted_rms_mrad"}`` for every night it was measured or planned in; ``planned`` and
    ``predicted_rms_mrad`` are None where the night did not record them."""
    nights = NightBook(store).nights()
    by_name = {n.name: n for n in nights}
    names = list(by_name)
    owner: dict[str, str | None] = {}
    looks: dict[tuple[str, int], list[float]] = {}
    planned: dict[tuple[str, int], dict] = {}
    for part in (ids[i:i + CHUNK] for i in range(0, len(ids), CHUNK)):
        marks = ",".join("?" * len(part))
        for r in store.query(
                "SELECT r.heliostat_id AS hid, c.name AS camp, m.error_mrad AS e FROM measurements m "
                "JOIN heliostat_runs r ON m.run_id=r.id JOIN campaigns c ON r.campaign_id=c.id "
                f"WHERE m.iteration=1 AND m.error_mrad IS NOT NULL AND r.heliostat_id IN ({marks})",
                tuple(part)):
            if r["camp"] not in owner:  # a few campaigns, many measurements
                owner[r["camp"]] = night_of(r["camp"], names)
            night = owner[r["camp"]]
            if night is not None:
                looks.setdefault((r["hid"], by_name[night].index), []).append(float(r["e"]))
        if store.schema_version >= HELIOSTATS_SCHEMA:
            for r in store.query(
                    "SELECT n.idx AS idx, h.heliostat_id AS hid, h.planned AS planned, "
                    "h.predicted_rms_mrad AS pred FROM night_heliostats h JOIN nights n ON h.night_id=n.id "
                    f"WHERE h.heliostat_id IN ({marks})", tuple(part)):
                planned[(r["hid"], int(r["idx"]))] = {"planned": int(r["planned"]), "pred": r["pred"]}
    out: dict[str, list[dict]] = {hid: [] for hid in ids}
    for n in nights:
        for hid in ids:
            e, p = looks.get((hid, n.index), []), planned.get((hid, n.index))
            if not e and p is None:
                continue
            out[hid].append({"night": n.index, "name": n.name, "kind": n.kind,
                             "planned": None if p is None else p["planned"], "measured": len(e),
                             "first_look_error_mrad": sum(e) / len(e) if e else None,
                             "predicted_rms_mrad": None if p is None else p["pred"]})
    return out

