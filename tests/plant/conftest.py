"""Fixtures of the plant-integration tests: a small copy of the demo plant and a database whose
heliostats have fitted models (recorded through the store as a campaign records them)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from controller.calibration.records import ModelRecord, RunRecord
from controller.config import config_sha256
from controller.geometry.model.tracking import TERMS
from controller.storage.db import CampaignStore

REPO = Path(__file__).resolve().parents[2]


def small_plant(path: Path, ids: tuple[str, ...] = ("H01", "H02", "H14")) -> Path:
    """The demo plant with only the heliostats ``ids`` (quick to load)."""
    data = yaml.safe_load((REPO / "configs" / "demo.yaml").read_text())
    data["heliostats"] = [h for h in data["heliostats"] if h["id"] in ids]
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def record_models(db: Path, config: Path, ids: list[str], seed: int, campaign: str = "fit") -> None:
    """One recorded run per heliostat with a model of random terms (a few mrad and mm)."""
    rng = np.random.default_rng(seed)
    with CampaignStore(db) as store:
        cid, _ = store.open_campaign(campaign, config_path=str(config), config_sha256=config_sha256(config),
                                     light_source="lamp", target="tower-target", queue=list(ids))
        for k, hid in enumerate(ids):
            params = {t.key: float(rng.normal(0.0, 2.0)) for t in TERMS}
            model = ModelRecord(params, {t.key: 0.5 for t in TERMS}, 0.2, 6)
            store.record_run(cid, RunRecord(hid, k, "calibrated", "done", 2, 0.0, 1.0, model=model))
        store.finish_campaign(cid, "finished")


@pytest.fixture
def fitted(tmp_path):
    """(config, database) with models for H01 and H02; H14 has none."""
    config = small_plant(tmp_path / "plant.yaml")
    db = tmp_path / "c.db"
    record_models(db, config, ["H01", "H02"], seed=7)
    return config, db
