"""Leave-one-out validation of the tracking model: fit on all samples but one, predict the one
left out — the open-loop error at a geometry the fit never saw.

The held-out error of sample k is the angle between the model's normal at k's steps and the
normal k measured (bisector of its source direction and the direction from the mirror centre
to its spot), mrad; the uncalibrated error is the same angle with the nominal kinematics.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model_fit import ModelFit, Sample, fit_model, normal_residual_mrad
from controller.geometry.tracking_model import TrackingModel


@dataclass(frozen=True)
class HeldOut:
    """One fold: index of the held-out sample, its error with the model fitted without it and
    with the nominal kinematics (mrad of mirror normal), and that fold's fit."""

    index: int
    held_out_mrad: float
    uncalibrated_mrad: float
    fit: ModelFit


def leave_one_out(kin: HeliostatKinematics, samples: Sequence[Sample], *, noise_mrad: float) -> list[HeldOut]:
    """Every fold of the module docstring (needs at least two samples)."""
    from controller.errors import InputError

    if len(samples) < 2:
        raise InputError("leave-one-out needs at least two records")
    out = []
    for k, s in enumerate(samples):
        fit = fit_model(kin, [t for i, t in enumerate(samples) if i != k], noise_mrad=noise_mrad)
        out.append(HeldOut(k, normal_residual_mrad(kin, fit.model, s),
                           normal_residual_mrad(kin, TrackingModel.zero(), s), fit))
    return out
