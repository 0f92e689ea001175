"""The frame pairs behind the measurements — and behind a capture that gave none (a run's
``run_frames``) — PNG files beside the database, with their hashes."""

from __future__ import annotations

import hashlib
from pathlib import Path

from controller.calibration.records import ImageRecord
from controller.io.images import write_bytes_atomic
from controller.storage.checks import has_table, resolved_image_path, stored_image_path


class ImageArchive:
    """Keeps each measurement's LOW/HIGH pair as ``<base>/<campaign>/<heliostat>-it<N>-<kind>.png``
    (written atomically); the returned :class:`ImageRecord` s go into the run's record."""

    def __init__(self, base: str | Path) -> None:
        self.base = Path(base)

    def save(self, campaign: str, heliostat_id: str, iteration: int, frame) -> list[ImageRecord]:
        import cv2

        out = []
        for kind, img in (("low", frame.low), ("high", frame.high)):
            p = self.base / campaign / f"{heliostat_id}-it{iteration}-{kind}.png"
            ok, buf = cv2.imencode(".png", img)
            if not ok:
                raise OSError(f"could not encode {p} as PNG")
            data = buf.tobytes()  # hashed as written: the file is not read back
            write_bytes_atomic(p, data)
            out.append(ImageRecord(kind, str(p), hashlib.sha256(data).hexdigest(),
                                   tuple(float(t) for t in frame.exposures)))
        return out


def insert_images(db, db_path: Path, table: str, owner: str, owner_id: int,
                  images: list[ImageRecord]) -> None:
    """Insert ``images`` into ``table`` (``images``: a measurement's, ``run_frames``: a run's
    capture that gave no measurement) under ``owner`` = ``owner_id``, inside the caller's
    transaction; paths stored relative to the database's folder where they lie under it."""
    for im in images:
        db.execute(f"INSERT INTO {table} ({owner}, kind, path, sha256, exposure_low_s, exposure_high_s) "
                   "VALUES (?,?,?,?,?,?)",
                   (owner_id, im.kind, stored_image_path(db_path, im.path), im.sha256, *im.exposures))


def failed_frames(store, campaign_ids: list[int]) -> list[dict]:
    """The HIGH frame of every capture of campaigns ``campaign_ids`` that gave no measurement
    (``run_frames``): campaign, heliostat, the run's status, where and why it failed, the file.
    None in a database older than the table."""
    if not campaign_ids or not has_table(store, "run_frames"):
        return []
    marks = ",".join("?" * len(campaign_ids))
    rows = store.query("SELECT c.id AS cid, c.name AS campaign, r.heliostat_id AS hid, r.status AS status, "
                       "r.fault_state AS state, r.fault_cause AS cause, f.path AS path FROM run_frames f "
                       "JOIN heliostat_runs r ON f.run_id=r.id JOIN campaigns c ON r.campaign_id=c.id "
                       f"WHERE f.kind='high' AND c.id IN ({marks}) ORDER BY f.id", tuple(campaign_ids))
    return [{"campaign_id": r["cid"], "campaign": r["campaign"], "heliostat": r["hid"], "status": r["status"],
             "state": r["state"], "cause": r["cause"], "path": resolved_image_path(store.path, r["path"])}
            for r in rows]
