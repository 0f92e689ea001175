"""The frame pairs behind the measurements: PNG files beside the database, with their hashes."""

from __future__ import annotations

import hashlib
from pathlib import Path

from controller.calibration.records import ImageRecord
from controller.io.images import write_atomic


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

            def w(t: Path, img=img) -> None:
                if not cv2.imwrite(str(t), img):
                    raise OSError(f"could not write {t}")
            write_atomic(p, w)
            out.append(ImageRecord(kind, str(p), hashlib.sha256(p.read_bytes()).hexdigest(),
                                   tuple(float(t) for t in frame.exposures)))
        return out
