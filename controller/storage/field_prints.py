"""The ``field_prints`` table: the field each heliostat's model was fitted on (docs/campaigns.md,
"A model and its field").

A tracking model corrects one heliostat's nominal kinematics at its surveyed position against
targets at known places. Applied to a heliostat that moved, or whose actuators were measured
anew, or against a target that moved, it is silently wrong. So every calibration campaign and
planned night records, before it measures, what its heliostats' models rest on (its
*fingerprint*, :func:`record_field`), and every command that reads models from a database
checks the configuration it is given against it first (:func:`check_field`):

* ``heliostat:<id>``: ``position_enu_m`` and the kinematics of both axes
  (``axes.<axis>.<key>`` for :data:`KINEMATICS`);
* ``target:<id>``: ``center_enu_m``, ``normal``, ``width_m``, ``height_m``.

A difference is refused with one line naming the heliostat (or target) and the key, exit 2
(:class:`FieldChanged`), unless the operator accepts it (``--accept-field-change``). A model
of a database older than the table has no fingerprint: it is checked by the sha256 of the
configuration its campaign recorded. A command whose ``--config`` was not given (the packaged
demo plant, ``$HELIOCAL_CONFIG``) is refused on a database made with another configuration.
"""

from __future__ import annotations

import json
import math

from controller.calibration.records import utc_now
from controller.config import PlantConfig, config_sha256
from controller.errors import InputError
from controller.storage.checks import has_table, json_column
from controller.storage.db import CampaignStore

# The keys of an axis its kinematics use (controller.geometry.kinematics, from_config).
KINEMATICS = ("increment", "initial_stroke_length", "offset", "pivot_radius", "initial_angle",
              "clockwise_axis_movement")
ACCEPT = "--accept-field-change"


class FieldChanged(InputError):
    """The field given is not the one the models were fitted on (exit 2)."""


def heliostat_keys(cfg: PlantConfig, hid: str) -> dict:
    """What heliostat ``hid``'s model rests on, by configuration key."""
    h = cfg.heliostat(hid)
    out: dict = {"position_enu_m": [float(v) for v in h.position_enu_m]}
    for axis in ("azimuth", "elevation"):
        a = getattr(h.axes, axis)
        out.update({f"axes.{axis}.{k}": getattr(a, k) for k in KINEMATICS})
    return out


def target_keys(cfg: PlantConfig, tid: str) -> dict:
    """Where target ``tid`` stands, by configuration key."""
    t = cfg.target(tid)
    return {"center_enu_m": [float(v) for v in t.center_enu_m], "normal": [float(v) for v in t.normal],
            "width_m": t.width_m, "height_m": t.height_m}


def record_field(store: CampaignStore, cfg: PlantConfig, ids: list[str], config_path: str,
                 sha256: str) -> None:
    """The fingerprint of heliostats ``ids`` and of every target of ``cfg``, as their models will
    be fitted now, replacing what was recorded for them (one transaction)."""
    now = utc_now()
    rows = [(f"heliostat:{hid}", heliostat_keys(cfg, hid)) for hid in ids]
    rows += [(f"target:{t.id}", target_keys(cfg, t.id)) for t in cfg.targets]
    with store.tx() as db:
        db.executemany("INSERT OR REPLACE INTO field_prints (subject, keys_json, config_path, config_sha256, "
                       "recorded_utc) VALUES (?,?,?,?,?)",
                       [(subject, json.dumps(keys), str(config_path), sha256, now) for subject, keys in rows])


def field_changes(store: CampaignStore, cfg: PlantConfig, ids: list[str], config: str) -> list[str]:
    """Every difference between ``cfg`` (read from file ``config``) and the field the models of
    heliostats ``ids`` were fitted on, one line each (heliostats without a model have nothing to
    differ from); empty when there is none."""
    models = set(store.latest_models(ids))
    if not models:
        return []
    prints = _prints(store)
    out = []
    for hid in (h for h in ids if h in models):
        rec = prints.get(f"heliostat:{hid}")
        if rec is None:
            out += _by_hash(store, hid, config)
            continue
        diff = _first_difference(heliostat_keys(cfg, hid), rec[0])
        if diff is not None:
            out.append(f"{config}: heliostat {hid}: {diff} when its model was fitted ({rec[1]})")
    for t in cfg.targets:
        rec = prints.get(f"target:{t.id}")
        diff = None if rec is None else _first_difference(target_keys(cfg, t.id), rec[0])
        if diff is not None:
            out.append(f"{config}: target {t.id}: {diff} when the models were fitted ({rec[1]})")
    return out


def check_field(store: CampaignStore, cfg: PlantConfig, ids: list[str], config: str, *, accept: bool = False,
                defaulted: bool = False) -> list[str]:
    """Refuse (:class:`FieldChanged`, one line naming the first heliostat or target and key, with
    how many more differ) a configuration whose field differs from the one the models of ``ids``
    were fitted on, unless ``accept``; returns the differences accepted. ``defaulted``: ``config``
    was not given by the user (a default): refused when the database was made with another
    configuration, whatever ``accept`` says."""
    if defaulted:
        made = store.query("SELECT config_path, config_sha256 FROM campaigns ORDER BY id DESC LIMIT 1")
        if made and made[0]["config_sha256"] != config_sha256(config):
            raise FieldChanged(f"{store.path} was made with the configuration {made[0]['config_path']}, not "
                               f"{config} (the default); pass --config FILE")
    changes = field_changes(store, cfg, ids, config)
    if changes and not accept:
        more = f" (and {len(changes) - 1} more)" if len(changes) > 1 else ""
        raise FieldChanged(f"{changes[0]}{more}; pass {ACCEPT} to use the models anyway")
    return changes


def _prints(store: CampaignStore) -> dict[str, tuple[dict, str]]:
    if not has_table(store, "field_prints"):
        return {}
    return {r["subject"]: (json_column(store.path, "field_prints", r, "keys_json", dict), r["config_path"])
            for r in store.query("SELECT rowid AS id, * FROM field_prints")}


def _first_difference(now: dict, then: dict) -> str | None:
    """``"<key> is <now> here, <then>"`` for the first key that differs, or None."""
    for key, value in now.items():
        if key not in then or not _same(value, then[key]):
            return f"{key} is {_show(value)} here, {_show(then.get(key))}"
    return None


def _same(a, b) -> bool:
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, bool) or isinstance(b, bool):
        return a == b
    if isinstance(a, int | float) and isinstance(b, int | float):
        return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-9)
    return a == b


def _show(v) -> str:
    return json.dumps(v)


def _by_hash(store: CampaignStore, hid: str, config: str) -> list[str]:
    """A model recorded before fingerprints: the configuration of its campaign against ``config``."""
    rows = store.query("SELECT c.config_path, c.config_sha256 FROM model_params m JOIN campaigns c "
                       "ON m.campaign_id=c.id WHERE m.heliostat_id=? ORDER BY m.id DESC LIMIT 1", (hid,))
    if not rows or rows[0]["config_sha256"] == config_sha256(config):
        return []
    return [f"{config}: heliostat {hid}: its model was fitted with another configuration "
            f"({rows[0]['config_path']}) and the database has no fingerprint of that field to compare key "
            "by key (recorded before heliocal kept one)"]
