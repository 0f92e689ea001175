"""A folder in the layout of the PAINT database, read and checked before anything is written.

Layout (that of PAINT's downloads, docs/import.md)::

    DIR/<H>/<H>_properties.json                               heliostat H's properties
    DIR/<H>/calibration/<id>_calibration_properties.json      its calibration records
    DIR/timestamps.json                                       "<H>_<id>": UTC time of each record
    DIR/tower-measurements.json                               the targets and the plant origin

Other files (PAINT's images, a README) are ignored. Every file goes through the bounded
readers of :mod:`controller.geometry.paint_io`; the first bad one ends the reading with an
InputError naming the file and key.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

from controller.errors import InputError
from controller.geometry.paint_io import (
    FOCAL_SPOT_METHODS,
    PaintRecord,
    Towers,
    check_reach,
    kinematics_from_properties,
    read_heliostat_properties,
    read_record,
)
from controller.io.files import read_bytes
from controller.io.text_numbers import is_ascii_index

RECORD_SUFFIX = "_calibration_properties.json"


@dataclass(frozen=True)
class FolderRecord:
    """One calibration record: its ids, file, the SHA-256 of its bytes, the record in the plant
    frame (its spot UTIS's, else HeliOS's: ``record.method``) and its UTC time (None: the
    timestamps file has none)."""

    heliostat_id: str
    record_id: str
    path: Path
    sha256: str
    record: PaintRecord
    utc: str | None


@dataclass(frozen=True)
class FolderHeliostat:
    heliostat_id: str
    properties_path: Path
    properties: dict
    records: list[FolderRecord]


def heliostat_folders(folder: str | Path) -> dict[str, tuple[Path, list[Path]]]:
    """Each heliostat of ``folder``: its properties file and record files (sorted by id)."""
    root = Path(folder)
    if not root.is_dir():
        raise InputError(f"{root}: not a folder (a PAINT folder holds <H>/<H>_properties.json)")
    out = {}
    for sub in sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")):
        props = sub / f"{sub.name}_properties.json"
        if not props.is_file():
            raise InputError(f"{props}: missing (each heliostat folder of a PAINT folder holds "
                             "<H>_properties.json)")
        records = sorted((sub / "calibration").glob(f"*{RECORD_SUFFIX}"),
                         key=lambda p: _id_key(p.name.removesuffix(RECORD_SUFFIX)))
        out[sub.name] = (props, records)
    if not out:
        raise InputError(f"{root}: no heliostat folder (<H>/<H>_properties.json)")
    return out


def _id_key(record_id: str) -> tuple:
    return (0, int(record_id), "") if is_ascii_index(record_id) else (1, 0, record_id)


def read_folder(folder: str | Path, towers: Towers, timestamps: dict[str, str]) -> list[FolderHeliostat]:
    """Every heliostat and record of ``folder`` (records in ``towers``' frame, spots preferring
    UTIS, each with its time from ``timestamps``), in heliostat-id order, each heliostat's
    records in time order (PAINT ids rise with time)."""
    out = []
    for hid, (props_path, paths) in heliostat_folders(folder).items():
        props = read_heliostat_properties(props_path)
        kin = kinematics_from_properties(props, towers.origin_wgs84, hid)
        records = []
        for p in paths:
            rid = p.name.removesuffix(RECORD_SUFFIX)
            sha = hashlib.sha256(read_bytes(p, "calibration record")).hexdigest()
            rec = read_record(p, towers, methods=FOCAL_SPOT_METHODS)
            check_reach(rec, kin)
            records.append(FolderRecord(hid, rid, p, sha, rec, timestamps.get(f"{hid}_{rid}")))
        records.sort(key=lambda r: (r.utc or "", _id_key(r.record_id)))
        out.append(FolderHeliostat(hid, props_path, props, records))
    return out
