"""A synthetic frame archive: a simulated field's recorded campaigns repeated over many nights.

Reprocessing is measured and tested on archives far larger than a demo run records. This
builds one from a real demo database: every campaign of the source copied ``copies`` times,
the k-th copy recorded k nights (or ``spacing_h`` hours) earlier (its own campaign, its own frame
files, hard-linked to the source's so a 5,000-pair archive costs no disk), through the product's
record store. The copies
carry the source's measurements, pairs and camera registrations; no models (reprocessing fits
them).
"""

from __future__ import annotations

import dataclasses
import os
import shutil
from datetime import datetime, timedelta
from pathlib import Path

from controller.calibration.records import ImageRecord
from controller.storage.db import CampaignStore, open_existing


def _earlier(stamp: str, hours: float) -> str:
    return (datetime.fromisoformat(stamp) - timedelta(hours=hours)).isoformat(timespec="milliseconds")


def _link(src: str, dst: Path) -> str:
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:  # another file system: copy
        shutil.copyfile(src, dst)
    return str(dst)


def replicate(source_db: Path, out_db: Path, images: Path, copies: int, spacing_h: float = 24.0) -> int:
    """Write ``out_db`` holding ``copies`` copies of every campaign of ``source_db`` (frames
    under ``images/<campaign>/``), the k-th recorded k × ``spacing_h`` hours earlier (24: a
    night each; less than 6 h apart they count as one night for the model's epochs); returns the
    number of frame pairs."""
    pairs = 0
    with open_existing(source_db) as src, CampaignStore(out_db) as out:
        campaigns = src.campaigns()
        for k in range(copies):
            for c in campaigns:
                name = f"{c.name}/copy-{k}"
                cid, _ = out.open_campaign(name, config_path=c.config_path, config_sha256=c.config_sha256,
                                           light_source=c.light_source, target=c.target, queue=c.queue,
                                           meta=c.meta)
                for run in src.runs(c.id):
                    ms = []
                    for m in src.measurements(c.id, run.heliostat_id):
                        imgs = [ImageRecord(i.kind, _link(i.path, images / name / Path(i.path).name),
                                            i.sha256, i.exposures) for i in src.images(m.id)]
                        pairs += len(imgs) == 2
                        ms.append(dataclasses.replace(m, measured_utc=_earlier(m.measured_utc, k * spacing_h),
                                                      images=imgs, id=None, run_id=None, campaign_id=None,
                                                      heliostat_id=None))
                    out.record_run(cid, dataclasses.replace(run, measurements=ms, corrections=[], model=None,
                                                            id=None))
                out.finish_campaign(cid, c.status if c.status != "running" else "finished", c.cause)
    return pairs
