"""The live view's gauge-line segments from a plan's nominal TCPs (``livefit.line_segments``): the
principal axis of each line's points, over their extent plus 20 mm at each end. Its memory is
linear in the points (``benchmarks/plan_scaling.py``: 20,000 points, 100,000 targets)."""

from __future__ import annotations

import numpy as np

from station.acquire.livefit import line_segments


def test_each_segment_runs_along_its_line_over_the_points_extent():
    rng = np.random.default_rng(0)
    directions = {3: np.array([0.6, 0.8, 0.0]), 7: np.array([0.0, -0.28, 0.96])}
    points, ids = [], []
    for lid, u in directions.items():
        s = rng.uniform(-150.0, 250.0, 400)
        noise = rng.normal(0.0, 0.05, (400, 3))  # mm, well below the 400 mm extent
        points.append(np.array([500.0, -200.0, 300.0]) * lid + np.outer(s, u) + noise)
        ids.append(np.full(400, lid))
    segments = line_segments(np.concatenate(points), np.concatenate(ids))
    assert sorted(segments) == [3, 7]
    for lid, u in directions.items():
        a, b = segments[lid]
        along = (b - a) / np.linalg.norm(b - a)
        assert abs(abs(along @ u) - 1.0) < 1e-5  # 0.05 mm noise over 400 mm: ~1e-7 rad off
        p = points[list(directions).index(lid)]
        extent = np.ptp((p - p.mean(axis=0)) @ along)
        assert abs(np.linalg.norm(b - a) - (extent + 40.0)) < 1e-6


def test_a_line_of_one_point_is_a_40_mm_segment_through_it():
    segments = line_segments(np.array([[1.0, 2.0, 3.0]]), np.array([0]))
    a, b = segments[0]
    assert np.allclose((a + b) / 2, [1.0, 2.0, 3.0]) and np.isclose(np.linalg.norm(b - a), 40.0)
