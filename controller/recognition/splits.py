"""Which generalisation a test view measures: the split of a test view against a library.

A rendered error set records per image the heliostat, light source, slant range and error
magnitude (manifest columns ``heliostat,source,slant_m,magnitude``; library entries carry them
as ``params``). Against the library's coverage a test view is

* ``held-out-geometry``: its light source (lamp vs sun, another lamp) is in no library entry;
* ``held-out-heliostat``: the source is covered but the heliostat is in no library entry;
* ``held-out-magnitude``: heliostat and source are covered, the magnitude differs from every
  library magnitude of its case by more than ``MAGNITUDE_TOL``;
* ``seen``: all three are covered (only framing, exposure and noise differ).

Views without these columns (or a library without params) belong to no split.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

SPLITS = ("seen", "held-out-magnitude", "held-out-heliostat", "held-out-geometry")
MAGNITUDE_TOL = 1e-3


@dataclass
class Coverage:
    """Heliostats, sources and per-case magnitudes present in a library's entries."""

    heliostats: set[str] = field(default_factory=set)
    sources: set[str] = field(default_factory=set)
    magnitudes: dict[str, set[float]] = field(default_factory=dict)

    @classmethod
    def of(cls, entries: Iterable) -> Coverage:
        cov = cls()
        for e in entries:
            p = e.params or {}
            if "heliostat" in p:
                cov.heliostats.add(str(p["heliostat"]))
            if "source" in p:
                cov.sources.add(str(p["source"]))
            if "magnitude" in p:
                cov.magnitudes.setdefault(e.label, set()).add(float(p["magnitude"]))
        return cov

    def split(self, label: str, extra: Mapping[str, str]) -> str | None:
        """The split of a test view (true ``label``, manifest ``extra`` columns), or None."""
        if not (self.heliostats and self.sources and self.magnitudes):
            return None
        try:
            helio, source, mag = str(extra["heliostat"]), str(extra["source"]), float(extra["magnitude"])
        except (KeyError, ValueError):
            return None
        if source not in self.sources:
            return "held-out-geometry"
        if helio not in self.heliostats:
            return "held-out-heliostat"
        if all(abs(mag - m) > MAGNITUDE_TOL for m in self.magnitudes.get(label, ())):
            return "held-out-magnitude"
        return "seen"
