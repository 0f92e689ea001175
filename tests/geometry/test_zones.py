"""Ray against box (controller.geometry.zones), checked against points sampled along the ray."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.geometry.zones import ray_box_entry, zone_entered

coord = st.floats(-20, 20, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(o=st.tuples(coord, coord, coord), d=st.tuples(coord, coord, coord),
       c=st.tuples(coord, coord, coord), size=st.tuples(*[st.floats(0.5, 10)] * 3))
def test_entry_agrees_with_sampled_points(o, d, c, size):
    o, d = np.array(o), np.array(d)
    if np.linalg.norm(d) < 1e-3:
        return
    d = d / np.linalg.norm(d)
    lo, hi = np.array(c) - np.array(size) / 2, np.array(c) + np.array(size) / 2
    t = np.arange(0.0, 80.0, 0.01)
    inside = np.all((o + t[:, None] * d >= lo) & (o + t[:, None] * d <= hi), axis=1)
    got = ray_box_entry(o, d, lo, hi)
    if inside.any():
        assert got is not None and abs(got - t[inside][0]) <= 0.011
    elif got is not None:  # a graze between two samples, or beyond the sampled reach
        p = o + (got + 1e-9) * d
        assert np.all(p >= lo - 1e-6) and np.all(p <= hi + 1e-6)


def test_axis_parallel_rays_and_the_stop_distance():
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([1.0, 1.0, 1.0])
    assert ray_box_entry([-2.0, 0.5, 0.5], [1.0, 0.0, 0.0], lo, hi) == 2.0
    assert ray_box_entry([-2.0, 1.5, 0.5], [1.0, 0.0, 0.0], lo, hi) is None  # beside, parallel
    assert ray_box_entry([0.5, 0.5, 0.5], [0.0, 0.0, 1.0], lo, hi) == 0.0  # starts inside
    assert ray_box_entry([2.0, 0.5, 0.5], [1.0, 0.0, 0.0], lo, hi) is None  # behind the origin
    boxes = np.array([[lo, hi], [lo + 5, hi + 5]])
    assert zone_entered([-2.0, 0.5, 0.5], [1.0, 0.0, 0.0], boxes) == 0
    assert zone_entered([-2.0, 0.5, 0.5], [1.0, 0.0, 0.0], boxes, max_t=1.5) is None  # stopped before
