"""What one measurement of a cycle yields: the beam seen on the target, the library's match,
and a correction step; :class:`BeamNotFound` when there is nothing to measure, :class:`NoBeam`
when the presence decision says there is no beam on the target at all."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Observation:
    """Beam seen on the target. ``centroid_px`` = (x col, y row); ``centroid_enu`` in m."""

    centroid_px: tuple[float, float]
    centroid_enu: tuple[float, float, float]
    hu: np.ndarray
    peak: float
    clipped: tuple[str, ...] = ()  # edges of the view the spot touches: its centroid is biased inward
    # A clipped spot's centre from its half-maximum contour (controller.imaging.clipped_spot),
    # m ENU, and its confidence in [0, 1]; None / 0 when not clipped or not estimable.
    clipped_centre_enu: tuple[float, float, float] | None = None
    clipped_confidence: float = 0.0
    # Descriptor stacks (flat) of widened copies of the frame, when the library claims no case
    # for ``hu`` (controller.recognition.widen): tried in order by the match.
    hu_widened: tuple[np.ndarray, ...] = ()


@dataclass(frozen=True)
class Step:
    """A correction in both units: axis angles in degrees and motor steps."""

    daz_deg: float
    del_deg: float
    daz_steps: int
    del_steps: int


class BeamNotFound(RuntimeError):
    """No usable beam spot in the image (none, or clipped by the edge of the view)."""


class NoBeam(BeamNotFound):
    """No beam on the target by the presence decision (:mod:`controller.imaging.presence`):
    ``statistic`` < ``threshold``. The cycle records ``no_beam`` and computes no correction
    from the frame (docs/campaigns.md, "No beam")."""

    def __init__(self, message: str, statistic: float, threshold: float) -> None:
        super().__init__(message)
        self.statistic = statistic
        self.threshold = threshold
