"""The measurement chain of a capture: HDR merge → beam analysis → target ENU → library match."""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

from controller.calibration.observations import BeamNotFound, Match, Observation
from controller.config import PlantConfig
from controller.errors import InputError
from controller.geometry.target_frame import TargetFrame


class BeamChain:
    """HDR merge → beam analysis → target ENU → library match, for one plant configuration."""

    def __init__(self, cfg: PlantConfig, library=None, threshold: float | None = None,
                 min_peak_fraction: float = 0.02) -> None:
        from controller.imaging.crf import Crf

        cam = cfg.camera
        self.cfg = cfg
        self.crf = Crf.load(cam.crf_file) if cam.crf_file else None
        self.frame = TargetFrame.from_config(cfg.target(), (cam.height_px, cam.width_px))
        self.threshold = cfg.calibration.threshold if threshold is None else threshold
        self.centroid_threshold = cfg.calibration.centroid_threshold
        self.library = library
        self.min_peak_fraction = min_peak_fraction
        self._mergers: dict[tuple[float, float], Any] = {}
        self._lock = threading.Lock()

    def merge(self, frame) -> np.ndarray:
        from controller.imaging.hdr import HdrMerger

        key = tuple(float(t) for t in frame.exposures)
        with self._lock:
            m = self._mergers.get(key)
            if m is None:
                cam = self.cfg.camera
                m = self._mergers[key] = HdrMerger(key, self.crf, "raised-cosine", cam.dark_offset_counts,
                                                   bit_depth=cam.bit_depth, read_noise=cam.read_noise_counts,
                                                   full_well=cam.full_well_electrons)
        return m.merge(frame.low, frame.high)

    def analyze(self, hdr: np.ndarray) -> Observation:
        import cv2

        from controller.imaging.beam import analyze, subtract_background

        try:
            r = analyze(hdr, threshold=self.threshold, background="auto")
        except InputError as exc:
            raise BeamNotFound(f"no beam spot in the image ({exc})") from None
        if r.pixels < 4:
            raise BeamNotFound(f"no beam spot in the image (only {r.pixels} pixels above threshold)")
        # The pointing centroid is the beam's energy centroid: every pixel above a low
        # threshold (calibration.centroid_threshold), not only the main region analyze()
        # keeps for the shape. A detached or dim lobe (canting error) carries beam energy
        # and must pull the aim too (docs/campaigns.md).
        signal = subtract_background(hdr, r.background)
        smooth = cv2.GaussianBlur(signal.astype(np.float32), (0, 0), 1.0)
        above = smooth > self.centroid_threshold * float(smooth.max())
        rows, cols = hdr.shape
        edges = [name for name, e in (("top", above[0]), ("bottom", above[-1]), ("left", above[:, 0]),
                                      ("right", above[:, -1])) if e.any()]
        if edges:  # a clipped spot's centroid is biased towards the inside
            raise BeamNotFound(f"beam spot clipped by the {'/'.join(edges)} edge of the camera view")
        w = np.where(above, signal, 0.0)
        tot = float(w.sum())
        if not tot > 0:
            raise BeamNotFound("no beam energy above the threshold")
        x = float(w.sum(axis=0) @ np.arange(cols)) / tot
        y = float(w.sum(axis=1) @ np.arange(rows)) / tot
        return Observation((x, y), tuple(self.frame.pixel_to_enu(x, y)), np.asarray(r.hu), float(r.peak))

    def match(self, hu: np.ndarray) -> Match | None:
        if self.library is None:
            return None
        m = self.library.match_hu(hu)
        return Match(m.label, m.distance, m.runner_up, m.runner_up_distance, m.unknown, m.correction_deg)
