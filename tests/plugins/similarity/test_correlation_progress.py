"""``analyses.distance_correlation`` shows progress inside its rows."""

from __future__ import annotations

import numpy as np

from mocapflow.framework import MotionDatabase
from mocapflow.framework.testing import synthetic_motion
from mocapflow.plugins.similarity.applications.correlation import DistanceCorrelationStudy


def test_correlation_study_shows_progress_inside_its_rows():
    """A row of the study is long (neighbours of every sample, then every column): the
    progress moves per column and, for a measure row's neighbour scan, per 32 samples, by
    weights that count distance evaluations; the result is the same as without a bar."""
    db = MotionDatabase([synthetic_motion(90, seed=s) for s in range(3)])
    study = DistanceCorrelationStudy(samples=40, k=8, measures=("D_quat", "F_E15", "F_E30"))
    two = ("F_E15", "D_quat")
    seen: list[tuple] = []
    given: list[float] = []

    def recorder(items, total=None, desc="", weights=None):
        given.extend(weights)
        for item in items:
            seen.append(item)
            yield item

    with_bar = study.study(db, progress=recorder, rows=two)
    assert len(seen) == len(given) == (1 + 3) + (2 + 3)  # F row: 1 neighbour unit; D row: 40 samples in 2
    n = db.n_frames
    assert given[4:6] == [32 * n, 8 * n]  # the scan's units weigh their samples x frames
    assert given[1:4] == [40 * 8] * 3  # a column: k distances per sample
    without = study.study(db, rows=two)
    for a, b in zip(with_bar[2:], without[2:], strict=True):
        np.testing.assert_array_equal(a, b)
