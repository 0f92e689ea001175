"""The true pose of a simulated heliostat now, read once and kept while its rods stand still.

The beam-safety monitor (50 times a second, every heliostat) and every rendered scene ask
for it, and most heliostats stand still most of the time: recomputing the hidden kinematics
(:mod:`simplant.truth`) for each was a large share of the demo's CPU.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from simplant.hidden import HiddenHeliostat


class PlantTruth(Protocol):
    """What the pose is read from: the plant's hidden heliostats and its night
    (:class:`simplant.plant.SimulatedPlant`, which imports this module, is one)."""

    hidden: dict[str, HiddenHeliostat]
    night: int


def true_pose(plant: PlantTruth, hid: str) -> tuple[np.ndarray, np.ndarray]:
    """(:meth:`SimulatedPlant.true_normal`, mirror centre) of ``hid`` at one read of its rods,
    kept in ``HiddenHeliostat.pose_cache`` while the rods, their repeatability draw and the
    night stay the same (the same values as computing them anew: same calls, same order)."""
    hh = plant.hidden[hid]
    steps = tuple(hh.controller.output_steps())
    jitter = hh.settle(steps, plant.night)
    key = (steps, jitter, plant.night)
    cached = hh.pose_cache
    if cached is not None and cached[0] == key:
        return cached[1], cached[2]
    n = hh.truth.normal(*steps, night=plant.night, jitter=jitter)
    c = hh.truth.mirror_center(*steps, night=plant.night)
    hh.pose_cache = (key, n, c)
    return n, c
