"""The field of the real plant: the :class:`controller.calibration.campaign.field.Field` built
from its configuration (drives through the link pool, each target's camera, the lamp panel,
wall time), and the record store it writes. The simulated plant's field is built in
:mod:`controller.commands.simulated`; both keep records in the same store and frames in
``images/`` beside the database.

Used by ``heliocal campaign run|night``, ``heliocal demo``, the console and OPC UA.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import ExitStack, closing, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from controller.calibration.campaign.field import Field, PanelLamps
from controller.commands.integration._plant import cli_user
from controller.config import PlantConfig, config_sha256
from controller.devices.factory import LinkPool, open_camera
from controller.devices.plant_time import PlantTime
from controller.errors import InputError
from controller.storage.alarms import AlarmBook
from controller.storage.audit import AuditTrail
from controller.storage.db import CampaignStore
from controller.storage.images import ImageArchive
from controller.storage.nights import NightBook


@dataclass
class FieldSession:
    """An open field with its night book; ``plant``: the simulated plant (its truth) or None."""

    field: Field
    book: NightBook
    plant: Any = None


def open_store(db: str | Path) -> CampaignStore:
    """The writer store of ``db`` with its campaign lock taken (DatabaseBusy names the owner),
    before any slow work."""
    store = CampaignStore(db)
    try:
        store.campaign_lock.acquire()
    except BaseException as exc:
        store.close(exc)
        raise
    return store


@contextmanager
def real_field(cfg: PlantConfig, config_path: str, store: CampaignStore, *,
               camera_manifest: str | None = None) -> Iterator[FieldSession]:
    """The configured field: ``camera_manifest`` replays recorded pairs for the calibration
    target, else each target's configured camera driver."""
    from controller.recognition.library_io import load_library

    lib = load_library(cfg.calibration.library) if cfg.calibration.library else None
    with ExitStack() as stack:
        if camera_manifest:
            cameras = {cfg.calibration.target: stack.enter_context(closing(open_camera(cfg.camera,
                                                                                       camera_manifest)))}
        else:
            cameras = {t: stack.enter_context(closing(_target_camera(cfg, t)))
                       for t in cfg.calibration.parallel_targets()}
        pool = stack.enter_context(LinkPool())
        time = PlantTime()
        lamps = None
        if cfg.lamps is not None:
            lamps = PanelLamps.open(cfg.lamps, time)
            stack.callback(lamps.close)
        images = ImageArchive(Path(store.path).parent / "images")
        yield FieldSession(plant_records(Field(cfg, str(config_path), config_sha256(config_path), store, pool,
                                               cameras, time, lamps, images, lib)), NightBook(store))


def _target_camera(cfg: PlantConfig, target: str):
    """The configured camera of ``target`` (:func:`controller.devices.factory.open_camera`);
    InputError naming the target when it has none."""
    try:
        return open_camera(cfg.camera_of(target))
    except InputError as exc:
        raise InputError(f"target {target}: {exc}") from None


def plant_records(field: Field) -> Field:
    """``field`` with its store's alarm list and audit trail (recording as the shell's user; the
    console and the OPC UA server record as the account that asked)."""
    field.alarms = AlarmBook(field.store)
    field.audit = AuditTrail(field.store, cli_user())
    return field
