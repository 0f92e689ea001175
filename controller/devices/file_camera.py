"""A double-CCD camera that replays image pairs listed in a manifest (YAML or JSON).

Manifest::

    pairs:
      - low: frames/0001_low.png      # paths relative to the manifest's folder
        high: frames/0001_high.png
        exposures: [0.010, 0.020]      # seconds, LOW first
        timestamp: 1700000000.0        # optional, seconds; default: the pair's index
        metadata: {heliostat: H01}     # optional

``capture()`` returns the pairs in order; after the last one it raises CameraError, or starts
again when ``loop=True``. A file camera cannot change its exposures: ``set_exposures`` only
records the request, which each pair's metadata reports as ``requested_exposures``.
"""

from __future__ import annotations

from pathlib import Path

from controller.devices.camera import CameraError, DoubleCcdCamera, FramePair
from controller.errors import HeliocalError, InputError
from controller.io.images import read_image
from controller.io.yaml_files import load_yaml


class FileCamera(DoubleCcdCamera):
    def __init__(self, manifest: str | Path, *, loop: bool = False) -> None:
        self.manifest = Path(manifest)
        doc = load_yaml(self.manifest, "manifest")  # bounded: size, UTF-8, nesting (JSON is YAML)
        pairs = doc.get("pairs") if isinstance(doc, dict) else None
        if not isinstance(pairs, list) or not pairs:
            raise InputError(f"{self.manifest}: pairs: required key is missing (a non-empty list)")
        self._entries = [self._entry(i, p) for i, p in enumerate(pairs)]
        self._next = 0
        self._loop = loop
        self._requested = self._entries[0]["exposures"]

    def _entry(self, i: int, item) -> dict:
        key = f"{self.manifest}: pairs[{i}]"
        if not isinstance(item, dict):
            raise InputError(f"{key}: must be a mapping with low, high, exposures")
        for k in ("low", "high", "exposures"):
            if k not in item:
                raise InputError(f"{key}.{k}: required key is missing")
        exp = item["exposures"]
        if (not isinstance(exp, list) or len(exp) != 2
                or not all(isinstance(t, (int, float)) and t > 0 for t in exp) or exp[0] > exp[1]):
            raise InputError(f"{key}.exposures: must be [t_low, t_high] in seconds, 0 < t_low <= t_high")
        base = self.manifest.parent
        low, high = base / str(item["low"]), base / str(item["high"])
        for k, p in (("low", low), ("high", high)):
            if not p.is_file():  # a FIFO or a device would block or never end when read
                state = "not a regular file" if p.exists() else "not found"
                raise InputError(f"{key}.{k}: image file {state}: {p}")
        meta = item.get("metadata", {})
        if not isinstance(meta, dict):
            raise InputError(f"{key}.metadata: must be a mapping")
        return {"low": low, "high": high, "exposures": (float(exp[0]), float(exp[1])),
                "timestamp": float(item.get("timestamp", i)), "metadata": meta}

    def __len__(self) -> int:
        return len(self._entries)

    @property
    def exposures(self) -> tuple[float, float]:
        return self._requested

    def set_exposures(self, t_low: float, t_high: float) -> None:
        self._requested = (float(t_low), float(t_high))

    def capture(self) -> FramePair:
        if self._next >= len(self._entries):
            if not self._loop:
                raise CameraError(f"{self.manifest}: all {len(self._entries)} pairs replayed")
            self._next = 0
        e = self._entries[self._next]
        self._next += 1
        try:
            low, high = read_image(e["low"]), read_image(e["high"])
        except HeliocalError as exc:
            raise CameraError(str(exc)) from None
        if low.shape != high.shape:
            raise CameraError(f"{e['low']} and {e['high']} differ in size: {low.shape} vs {high.shape}")
        meta = dict(e["metadata"], source=str(e["low"]), requested_exposures=self._requested)
        return FramePair(low, high, e["exposures"], e["timestamp"], meta)
