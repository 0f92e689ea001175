"""Sessions and the random-walk prior of the references' drift (model_drift, Eq. 1)."""

import numpy as np
import pytest

from controller.geometry.model.drift import RandomWalk, chain_precision, sessions


def test_sessions_split_at_gaps_and_unknown_times_join_the_newest():
    """Measurements without a gap of 6 h are one session (a night across midnight is one);
    sessions run oldest first; a measurement without a time belongs to the newest."""
    walk = RandomWalk(0.1e-3, gap_days=0.25)
    t = [10.84, 11.08, 11.875, 13.85, None]  # 20:10, 01:55 next day, 21:00, two days later, unknown
    s = sessions(t, walk)
    assert s.index.tolist() == [0, 0, 1, 2, 2]
    assert s.times == pytest.approx([11.08, 11.875, 13.85])
    gaps = np.array([11.875 - 11.08, 13.85 - 11.875])
    assert s.step_sd == pytest.approx(0.1e-3 * np.sqrt(gaps))
    # u_e: the marginal σ of a session's references relative to the newest.
    assert s.scale == pytest.approx([0.1e-3 * np.sqrt(gaps.sum()), 0.1e-3 * np.sqrt(gaps[1])])
    assert sessions([None, None], walk).count == 1


def test_the_chain_prior_is_the_random_walk():
    """The precision LᵀL over the whitened offsets gives back the random walk's covariance:
    Cov(d_e, d_f) = σ² × (days from the later of e, f to the newest)."""
    walk = RandomWalk(0.2e-3, jump=0.05e-3)
    s = sessions([0.0, 3.0, 10.0, 30.0], walk)
    cov_y = np.linalg.inv(chain_precision(s, components=1))
    cov_d = cov_y * np.outer(s.scale, s.scale)
    back = np.array([30.0, 27.0, 20.0])  # days from each earlier session to the newest
    jumps = np.array([3, 2, 1])  # session steps from each to the newest
    expected = 0.2e-3**2 * np.minimum.outer(back, back) + 0.05e-3**2 * np.minimum.outer(jumps, jumps)
    assert cov_d == pytest.approx(expected, rel=1e-9)
