"""Whose spot is where: the truth of every rendered scene, and a fault that exchanges two spots.

Each render of the plant's scene records, per heliostat whose beam is in view, where its spot's
centre is on the target plane (m ENU). A measurement recorded under heliostat h is
**misassigned** when its centroid lies nearer another heliostat's spot than h's own in the
latest render with h's beam in view (:meth:`SpotTruth.misassigned`).

The fault :meth:`SpotTruth.swap` exchanges two heliostats' spots while both beams are in view:
each lands where the other's was when they first met (a frozen offset, so each spot still
moves with its own heliostat's steps) — what two heliostats pointing far off, each onto the
other's slot, would look like. Its truth follows the light: the spot made by a is recorded
as a's, where it lands. The fault :meth:`SpotTruth.stray` moves only one of the two, where the
other's was when they first met: a heliostat pointing far off, towards another's slot. The
fault :meth:`SpotTruth.freeze` keeps one spot where it was first drawn, whatever its heliostat
does: a mirror that does not follow its drive (a slipping coupling), whose spot never moves
with its identity step.
"""

from __future__ import annotations

import threading
from collections import deque

import numpy as np


class SpotTruth:
    def __init__(self, keep: int = 32) -> None:
        self.log: deque[dict[str, np.ndarray]] = deque(maxlen=keep)
        self.pair: tuple[str, str] | None = None
        self._offsets: dict[str, np.ndarray] | None = None
        self._both = True  # swap: both spots move; stray: only the first
        self.frozen: str | None = None
        self._first: np.ndarray | None = None  # where the frozen spot was first drawn (relative)
        self._lock = threading.Lock()
        self.misassigned_count = 0
        self.checked = 0
        self.errors_m: list[float] = []  # per measurement: centroid to its own spot's centre, m

    def swap(self, a: str, b: str) -> None:
        """Exchange the spots of ``a`` and ``b`` whenever both beams are in view (module docstring)."""
        with self._lock:
            self.pair, self._offsets, self._both = (a, b), None, True

    def stray(self, a: str, onto: str) -> None:
        """Move ``a``'s spot where ``onto``'s was when both beams were first in view, whenever
        both are (a frozen offset, as :meth:`swap`); ``onto``'s spot stays where it is."""
        with self._lock:
            self.pair, self._offsets, self._both = (a, onto), None, False

    def freeze(self, a: str) -> None:
        """Keep ``a``'s spot where it is next drawn, whatever ``a`` does (module docstring)."""
        with self._lock:
            self.frozen, self._first = a, None

    def shifts(self, rels: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Offsets (m ENU) of the swapped (or frozen) spots for this render (empty when the
        faults are off or only one of the two beams is in view)."""
        with self._lock:
            out = {}
            if self.frozen in rels:
                if self._first is None:
                    self._first = np.asarray(rels[self.frozen], float)
                out[self.frozen] = self._first - rels[self.frozen]
            if self.pair is None or not all(h in rels for h in self.pair):
                self._offsets = None
                return out
            if self._offsets is None:
                a, b = self.pair
                self._offsets = {a: rels[b] - rels[a]}
                if self._both:
                    self._offsets[b] = rels[a] - rels[b]
            return {**out, **self._offsets}

    @staticmethod
    def place(image: np.ndarray, grid, at_enu, shift) -> np.ndarray:
        """``image`` (one spot rendered on ``grid``) moved by ``shift`` m ENU (None: as is)."""
        if shift is None:
            return image
        import cv2

        x0, y0 = grid.enu_to_pixel(np.asarray(at_enu, float))
        x1, y1 = grid.enu_to_pixel(np.asarray(at_enu, float) + shift)
        m = np.float32([[1, 0, float(x1 - x0)], [0, 1, float(y1 - y0)]])
        rows, cols = image.shape
        return cv2.warpAffine(image.astype(np.float32), m, (cols, rows), flags=cv2.INTER_LINEAR).astype(float)

    def record(self, spots: dict[str, np.ndarray]) -> None:
        """One render's spots: heliostat -> spot centre, m ENU."""
        with self._lock:
            self.log.append({h: np.asarray(r, float) for h, r in spots.items()})

    def misassigned(self, hid: str, centroid_rel: np.ndarray) -> bool:
        """Is a centroid (m ENU) recorded under ``hid`` another's spot? Judged on the latest
        render with ``hid``'s beam in view (the capture its measurement came from, or the step's
        capture just after it): the centroid is nearer another heliostat's spot there than its
        own. Counted in ``misassigned_count`` (of ``checked``); the distance from the centroid to
        its own spot's centre (the reflected central ray's hit) in the recent render nearest it
        is kept in ``errors_m``."""
        c = np.asarray(centroid_rel, float)
        with self._lock:
            last = next((s for s in reversed(self.log) if hid in s), None)
            wrong = last is None or any(np.linalg.norm(r - c) < np.linalg.norm(last[hid] - c)
                                        for h, r in last.items() if h != hid)
            own = [np.linalg.norm(s[hid] - c) for s in self.log if hid in s]
            if own:  # the capture it came from: the render whose own spot is nearest
                self.errors_m.append(float(min(own)))
            self.checked += 1
            self.misassigned_count += int(wrong)
        return wrong
