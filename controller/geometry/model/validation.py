"""Validation of the tracking model on records it was not fitted to: the open-loop error at
geometries and times the fit never saw.

Two protocols: leave-one-out (:func:`leave_one_out`: fit on all samples but one, predict the
one left out) and a split (:func:`held_out`: fit on a training set, predict every held-out
record; the splits of :mod:`controller.geometry.model.splits`).

The held-out error of a record is the angle between the normal its *predicted* focal spot
implies and the normal its *measured* spot implies, both the bisector of the source direction
and the direction from the heliostat's surveyed position to the spot, mrad. It is what a
plant sees: where the beam lands. Leave-one-out compares the model's normal with the measured
one at the model's mirror centre (the same to a few µrad).

The peer a tracking model has to beat is a rigid rotation R of the nominal normals,

    R = argmin_R Σ_k |R n_k⁰ − m_k|²                                          (1)

over the training records (n⁰ the nominal normal, m the measured one), solved in closed form
by the SVD of Σ n_k⁰ m_kᵀ (Kabsch 1976 [1]): three angles, no kinematics.

References
----------
.. [1] W. Kabsch, "A solution for the best rotation to relate two sets of vectors", Acta
   Crystallographica A32, 922–923, 1976.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from controller.geometry.aiming import angle_mrad, intersect_plane, reflected_beam
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model.drift import DRIFTING, offsets_at
from controller.geometry.model.fit import ModelFit, Sample, fit_model, normal_residual_mrad
from controller.geometry.model.start import implied_normals
from controller.geometry.model.tracking import NAMES, TrackingModel
from controller.geometry.pose_batch import normal_and_center

_OFFSETS = np.array([NAMES.index(n) for n in DRIFTING])


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


def kabsch(nominal: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """The rotation R (3, 3) of Eq. (1) between unit vectors ``nominal`` and ``measured`` (K, 3)."""
    u, _, vt = np.linalg.svd(nominal.T @ measured)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


@dataclass(frozen=True, eq=False)  # numpy fields
class Targets:
    """Each record's target plane: a point and the unit normal (K, 3), m ENU."""

    points: np.ndarray
    normals: np.ndarray


def spot_errors_mrad(kin: HeliostatKinematics, samples: Sequence[Sample], normals: np.ndarray,
                     centers: np.ndarray, targets: Targets) -> np.ndarray:
    """Held-out error of the module docstring (K,) for predicted mirror ``normals`` and mirror
    ``centers`` (K, 3) at the samples' steps; NaN where a normal could not be evaluated."""
    out = np.full(len(samples), np.nan)
    for k, s in enumerate(samples):
        if not (np.all(np.isfinite(normals[k])) and np.all(np.isfinite(centers[k]))):
            continue
        spot = intersect_plane(centers[k], reflected_beam(s.source_dir, normals[k]), targets.points[k],
                               targets.normals[k])
        pos = kin.position[None]
        m = implied_normals(pos, s.source_dir[None], np.asarray(spot, float)[None])
        meas = implied_normals(pos, s.source_dir[None], np.asarray(s.spot_enu, float)[None])
        out[k] = float(angle_mrad(m[0], meas[0]))
    return out


def at_times(fit: ModelFit, times: Sequence[float | None]) -> np.ndarray:
    """The fitted model's values (K, n) SI at each of ``times`` (days): its references moved
    by the drift the fit found at that time (:func:`controller.geometry.model.drift.offsets_at`;
    the newest session's model after it or without a time)."""
    values = np.repeat(fit.model.values[None], len(times), axis=0)
    if fit.drift_mrad is not None:
        for k, t in enumerate(times):
            values[k, _OFFSETS] += 1e-3 * offsets_at(fit.session_times, fit.drift_mrad, t)
    return values


@dataclass(frozen=True, eq=False)  # numpy fields
class SplitResult:
    """Held-out errors (mrad) of the model, of the rigid rotation of Eq. (1) and of the nominal
    kinematics on the same held-out records, and the training fit."""

    model_mrad: np.ndarray
    rotation_mrad: np.ndarray
    nominal_mrad: np.ndarray
    fit: ModelFit


def held_out(kin: HeliostatKinematics, train: Sequence[Sample], test: Sequence[Sample], targets: Targets,
             **fit_options) -> SplitResult:
    """Fit on ``train`` (``fit_options`` as :func:`fit_model` takes them), predict ``test`` (its
    ``targets``): the model, the rotation peer and the nominal kinematics."""
    fit = fit_model(kin, train, **fit_options)
    steps = np.array([[s.az_steps, s.el_steps] for s in test], float)
    n, c = normal_and_center(kin, at_times(fit, [s.time_days for s in test]), steps)
    model = spot_errors_mrad(kin, test, n, c, targets)
    tr_steps = np.array([[s.az_steps, s.el_steps] for s in train], float)
    n0_tr, c0_tr = normal_and_center(kin, np.zeros((1, len(fit.model.values))), tr_steps)
    measured = implied_normals(c0_tr, np.array([s.source_dir for s in train]),
                               np.array([s.spot_enu for s in train]))
    ok = np.all(np.isfinite(n0_tr), axis=1)
    n0, c0 = normal_and_center(kin, np.zeros((1, len(fit.model.values))), steps)
    if ok.sum() >= 2:
        rot = kabsch(n0_tr[ok], measured[ok])
        rotation = spot_errors_mrad(kin, test, n0 @ rot.T, c0, targets)
    else:  # the nominal kinematics cannot evaluate the training steps: no rotation to fit
        rotation = np.full(len(test), np.nan)
    return SplitResult(model, rotation, spot_errors_mrad(kin, test, n0, c0, targets), fit)
