"""The ``calibration.search:`` section of the plant configuration (docs/configuration.md,
docs/commissioning.md "First light on a new field"): the beam search of a heliostat whose spot
is not in the camera's view. Re-exported by :mod:`controller.config`."""

from __future__ import annotations

from pydantic import Field

from controller.config_rules import Section


class BeamSearch(Section):
    max_looks: int = Field(
        default=0, ge=0, le=500, description="looks of the beam search before a heliostat whose spot is "
        "not in view ends no_beam (0: no search)")
    normal_sigma_mrad: float = Field(
        default=10.0, gt=0, le=1000, description="1-σ per axis of a heliostat's mirror-normal error before "
        "its first measurement (mrad): the search's extent and how far such a heliostat parks")
    extent_sigma: float = Field(
        default=3.0, gt=0, le=10, description="the search covers the beam's expected position out to "
        "this many σ")
    overlap_sigma: float = Field(
        default=1.0, ge=0, le=10, description="neighbouring looks overlap by this many σ of the predicted "
        "spot's size")
