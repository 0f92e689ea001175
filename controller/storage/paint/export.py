"""Export measurements as PAINT-style calibration-properties JSON records.

One file per measurement, ``<heliostat>-c<campaign>-m<measurement>-calibration-properties.json``,
with the keys of the PAINT database's records (as in tests/data/real/paint/):

* ``motor_position.axis_1_motor_position`` = elevation actuator steps and
  ``axis_2_motor_position`` = azimuth actuator steps (PAINT/ARTIST actuator order);
* ``target_name``: the measurement's target;
* ``focal_spot.heliocal`` = measured beam centroid as WGS84 [lat_deg, lon_deg, alt_m],
  converted from plant ENU about the site origin (controller.geometry.frames.enu_to_wgs84);
  a record imported from PAINT (``heliocal import paint``) keeps its method's key
  (``UTIS`` or ``HeliOS``);
* ``sun_azimuth`` / ``sun_elevation`` = the light source's direction seen from the heliostat,
  degrees, with PAINT's azimuth convention: **from south, positive towards east**,
  ``sun_azimuth = 180 - azimuth_from_north_clockwise`` folded into (-180, 180]. For a lamp
  the "sun" keys hold the lamp direction (``heliocal.light_source`` says which).

A ``heliocal`` object adds what PAINT has no key for (ids, ENU centroid, error, match).
"""

from __future__ import annotations

from pathlib import Path

from controller.calibration.records import CampaignRecord, MeasurementRecord
from controller.errors import InputError
from controller.geometry.frames import enu_to_wgs84
from controller.io.images import write_atomic
from controller.io.json_files import dumps_json
from controller.storage.db import CampaignStore


def paint_azimuth(azimuth_north_deg: float) -> float:
    """Our azimuth (clockwise from north) to PAINT's (from south, positive east), (-180, 180]."""
    a = (180.0 - float(azimuth_north_deg)) % 360.0
    return a - 360.0 if a > 180.0 else a


def paint_record(m: MeasurementRecord, campaign: CampaignRecord, site: tuple[float, float, float],
                 target: str | None = None, imported: tuple[str, str] | None = None) -> dict:
    """The PAINT-style record of one stored measurement of ``campaign`` on ``target`` (default
    the campaign's); ``imported``: (record id, focal-spot method) of a measurement imported from
    PAINT, whose spot is then written under its method's key, as it came."""
    rec = {
        "motor_position": {
            "axis_1_motor_position": int(m.el_steps),
            "axis_2_motor_position": int(m.az_steps),
        },
        "target_name": target or campaign.target,
        "sun_elevation": float(m.source_el_deg),
        "sun_azimuth": paint_azimuth(m.source_az_deg),
    }
    if m.centroid_enu is not None:
        lat, lon, alt = enu_to_wgs84(list(m.centroid_enu), *site)
        rec["focal_spot"] = {imported[1] if imported else "heliocal": [float(lat), float(lon), float(alt)]}
    rec["heliocal"] = {
        "heliostat_id": m.heliostat_id,
        "campaign_id": campaign.id,
        "measurement_id": m.id,
        "iteration": int(m.iteration),
        "light_source": campaign.light_source,
        "light_source_direction_enu": list(m.source_dir),
        "focal_spot_enu_m": None if m.centroid_enu is None else list(m.centroid_enu),
        "error_mrad": m.error_mrad,
        "matched_label": m.matched_label,
        "match_distance": m.match_distance,
        "measured_utc": m.measured_utc,
        "method": f"imported from PAINT ({imported[1]})" if imported else "heliocal HDR double-CCD centroid",
    }
    if imported:
        rec["heliocal"]["paint_record_id"] = imported[0]
    return rec


def export_paint(
    store: CampaignStore,
    out_dir: str | Path,
    site: tuple[float, float, float] | None = None,
    campaign_id: int | None = None,
) -> list[Path]:
    """Write one record per measurement (of one campaign, or all); returns the paths.

    ``site`` (lat_deg, lon_deg, elevation_m) is the ENU origin; by default it is taken from the
    campaign's stored metadata."""
    out = Path(out_dir)
    paths = []
    campaigns: dict[int, CampaignRecord] = {}
    targets = {r["id"]: r["target"] for r in store.query("SELECT id, target FROM measurements")}
    imported = {r["measurement_id"]: (r["record_id"], r["method"])
                for r in store.query("SELECT measurement_id, record_id, method FROM imported_records")}
    for m in store.measurements(campaign_id=campaign_id):
        cid = int(m.campaign_id)
        if cid not in campaigns:
            campaigns[cid] = store.campaign(cid)
            if site is None and "site" not in campaigns[cid].meta:
                raise InputError(
                    f"{store.path}: campaign {cid} has no site origin stored; pass --config to give it"
                )
        camp = campaigns[cid]
        rec = paint_record(m, camp, site or tuple(camp.meta["site"]), targets.get(m.id), imported.get(m.id))
        p = out / f"{m.heliostat_id}-c{cid}-m{m.id}-calibration-properties.json"
        text = dumps_json(rec, indent=4) + "\n"
        write_atomic(p, lambda t, text=text: t.write_text(text, encoding="utf-8"))
        paths.append(p)
    return paths
