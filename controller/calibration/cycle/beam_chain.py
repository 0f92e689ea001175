"""The measurement chain of a capture: HDR merge → beam analysis → target ENU → library match."""

from __future__ import annotations

import threading

import numpy as np

from controller.calibration.cycle.observations import BeamNotFound, NoBeam, Observation
from controller.config import PlantConfig
from controller.errors import InputError, NoBeamError
from controller.geometry.target_frame import TargetFrame
from controller.imaging.background import subtract_background
from controller.imaging.beam import analyze
from controller.imaging.centroid import SPECK_SIGMAS, energy_centroid
from controller.imaging.clipped_spot import clipped_centre
from controller.imaging.crf_io import load_crf
from controller.imaging.hdr import HdrMerger
from controller.recognition.library import Match

# A beam's smoothed peak stands this many noise σ above the background, or there is no beam
# (a heliostat at stow leaves only noise, whose "spot" touches every edge).
MIN_PEAK_SNR = 10.0


class BeamChain:
    """HDR merge → beam analysis → target ENU → library match, for one plant configuration."""

    def __init__(self, cfg: PlantConfig, library=None, threshold: float | None = None,
                 min_peak_fraction: float = 0.02) -> None:
        cam = cfg.camera
        self.cfg = cfg
        self.crf = load_crf(cam.crf_file) if cam.crf_file else None
        self.frame = TargetFrame.from_config(cfg.target(), (cam.height_px, cam.width_px))
        self.threshold = cfg.calibration.threshold if threshold is None else threshold
        self.centroid_threshold = cfg.calibration.centroid_threshold
        self.library = library
        self.min_peak_fraction = min_peak_fraction
        self._mergers: dict[tuple[float, float], HdrMerger] = {}
        self._lock = threading.Lock()
        # Set by the campaign's registration step (camera.registration): the pair is then
        # rectified onto ``frame`` before the merge (controller.calibration.cycle.registration_step).
        self.registration = None

    def merge(self, frame) -> np.ndarray:
        """The HDR image of a frame pair in the target frame (rectified first when registered)."""
        key = (float(frame.exposures[0]), float(frame.exposures[1]))
        with self._lock:
            m = self._mergers.get(key)
            if m is None:
                m = HdrMerger.from_camera_config(self.cfg.camera, self.crf, exposures=key)
                self._mergers[key] = m
        if self.registration is not None:
            return m.merge(*self.registration.rectify(frame))
        return m.merge(frame.low, frame.high)

    def analyze(self, hdr: np.ndarray, *, allow_clipped: bool = False) -> Observation:
        """The beam in ``hdr``; :class:`NoBeam` when the presence decision finds none,
        BeamNotFound when no usable spot is left. A spot clipped by the view's edge is
        refused too, unless ``allow_clipped`` (the cycle then corrects towards it and looks
        again): its centroid is biased towards the inside, right in direction only."""
        try:
            # The shape (Hu moments) and the plane the energy centroid below is taken over are
            # those the library and the campaign's accuracy were measured with.
            r = analyze(hdr, threshold=self.threshold, background="auto", centroid="segment")
        except NoBeamError as exc:
            d = exc.detail
            raise NoBeam(f"no beam on the target ({exc}); is the light source lit and confirmed, does "
                         "the camera see this target, did the beam miss it?", d["statistic"],
                         d["threshold"]) from None
        except InputError as exc:
            raise BeamNotFound(f"no beam spot in the image ({exc})") from None
        if r.pixels < 4:
            raise BeamNotFound(f"no beam spot in the image (only {r.pixels} pixels above threshold)")
        # The pointing centroid is the beam's energy centroid: every pixel above a low
        # threshold (calibration.centroid_threshold), not only the main region analyze()
        # keeps for the shape. A detached or dim lobe (canting error) carries beam energy
        # and must pull the aim too (docs/campaigns.md).
        signal = subtract_background(hdr, r.background)
        c = energy_centroid(signal, self.centroid_threshold, min_sigmas=SPECK_SIGMAS)  # not noise specks
        noise = r.background.noise
        if not c.peak > MIN_PEAK_SNR * noise:
            raise BeamNotFound(f"no beam spot found (peak {c.peak:.4g} is within {MIN_PEAK_SNR:g}x the "
                               f"background noise σ {noise:.4g}; is the beam on the target?)")
        if c.clipped and not allow_clipped:
            raise BeamNotFound(f"beam spot clipped by the {'/'.join(c.clipped)} edge of the camera view")
        if not c.total > 0:
            raise BeamNotFound("no beam energy above the threshold")
        enu = tuple(self.frame.pixel_to_enu(c.x, c.y))
        centre, conf = None, 0.0
        if c.clipped:  # where the spot's centre lies beyond the edge (the cycle's coarse correction)
            px, conf = clipped_centre(signal, self.centroid_threshold, tuple(c.clipped), (c.x, c.y))
            centre = tuple(float(v) for v in self.frame.pixel_to_enu(*px)) if px is not None else None
        # The shape features the library matches on: Hu moments at its own threshold(s) (a
        # multi-threshold library needs the whole stack), else the analysis' Hu moments.
        stacks = ([np.asarray(s, float).reshape(-1) for s in self.library.descriptors(hdr, self.threshold)]
                  if self.library is not None else [np.asarray(r.hu)])
        return Observation((c.x, c.y), enu, stacks[0], float(r.peak), tuple(c.clipped), centre, conf,
                           tuple(stacks[1:]))

    def match(self, obs: Observation) -> Match | None:
        if self.library is None:
            return None
        return self.library.match_stacks([obs.hu, *obs.hu_widened])
