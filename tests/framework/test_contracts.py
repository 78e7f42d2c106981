"""The matcher and cleaner contracts of the core, as a third party uses them.

A matcher implementing only ``match(query, space)`` and a cleaner implementing only
``detect``/``repair`` pass the conformance suite and run as pipeline steps through the
core's default ``run`` (no built-in module imported by the components themselves).
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

from mocapflow.framework import Cleaner, DataError, Matcher, MocapflowError, schema
from mocapflow.framework.cleaning import check_take, digression_table, edits_table
from mocapflow.framework.matching import MatchParams, QueryMatches, SearchSpace, min_frames_of, select_matches
from mocapflow.framework.queries import parse_query_spec
from mocapflow.framework.testing import (
    ReferenceIndex,
    check_cleaner,
    check_matcher,
    check_matcher_pipeline,
    synthetic_motion,
    synthetic_space,
)


class DiagonalMatcher(Matcher):
    """Toy matcher: every window of the query's length, aligned frame to frame (no warping)."""

    name = "diagonal"
    needs_index = False
    needs_features = True
    Params = MatchParams
    test_pipeline = {
        "steps": {"feat": {"uses": "features.end_effectors", "input": "motions"}},
        "inputs": {"database": "feat", "query": "motions"},
        "with": {"queries": ["synthetic2:10-40"], "count": 3},
        "bad_inputs": {"database": "feat", "query": "motions", "features": "motions"},
    }

    def match(self, query: np.ndarray, space: SearchSpace) -> QueryMatches:
        x = space.features
        if x is None:
            raise DataError("diagonal matching needs the database features")
        q = np.asarray(query, np.float64)
        if q.ndim != 2 or q.shape[0] < 1 or q.shape[1] != x.shape[1] or not np.isfinite(q).all():
            raise DataError(f"query must be finite (m >= 1, {x.shape[1]}), got {q.shape}")
        m, n = len(q), space.n_rows
        cost = np.full(n, np.inf)
        for e in range(m - 1, n):
            s = e - m + 1
            if space.continues[s + 1 : e + 1].all():
                cost[e] = np.linalg.norm(x[s : e + 1] - q, axis=1).sum()
        ends = np.arange(n, dtype=np.int64)
        start, length = ends - m + 1, np.full(n, m, np.int64)
        p = self.params
        keep = select_matches(
            ends,
            start,
            cost,
            length,
            count=p.count,
            max_cost=p.max_cost,
            rank_by=p.rank_by,
            min_frames=min_frames_of(p.min_span, m),
        )
        paths = [np.stack([np.arange(m), np.arange(start[k], start[k] + m)], 1) for k in keep]
        return QueryMatches(start[keep], ends[keep] + 1, cost[keep], length[keep], paths)


class SmoothingCleaner(Cleaner):
    """Toy cleaner: a frame whose rotation jumps from both neighbours is an error, repaired by slerp-free averaging."""

    name = "smoothing"

    class Params(Cleaner.Params):
        degrees: float = 20.0

    def detect(self, motion, context=None) -> np.ndarray:
        check_take(motion, self.key())
        if context is not None and not isinstance(context, (list, tuple)):
            raise DataError(f"context must be a list of motions, got {type(context).__name__}")
        q = motion.rotations
        out = np.zeros((motion.n_frames, motion.n_joints))
        if motion.n_frames >= 3:
            dot = np.abs(np.sum(q[1:-1] * q[:-2], -1)), np.abs(np.sum(q[1:-1] * q[2:], -1))
            ang = np.rad2deg(2 * np.arccos(np.clip(np.minimum(*dot), 0, 1)))
            out[1:-1] = np.clip(ang / (2 * self.params.degrees), 0, 1)
        return out

    def repair(self, motion, context=None):
        flagged = self.detect(motion, context) > 0.5
        rot = motion.rotations.copy()
        f, j = np.nonzero(flagged)
        avg = motion.rotations[f - 1, j] + motion.rotations[f + 1, j]
        rot[f, j] = avg / np.linalg.norm(avg, axis=-1, keepdims=True)
        cleaned = motion.with_arrays(rotations=rot)
        return cleaned, edits_table(motion, cleaned)


def test_a_matcher_implementing_only_match_conforms():
    check_matcher(DiagonalMatcher)


def test_a_matcher_implementing_only_match_runs_through_the_default_step():
    check_matcher_pipeline(DiagonalMatcher)


def test_a_cleaner_implementing_detect_and_repair_conforms():
    check_cleaner(SmoothingCleaner)


def test_the_default_cleaner_step_writes_the_shared_tables(tmp_path):
    from mocapflow.framework.conformance import run_test_pipeline

    ds = run_test_pipeline(SmoothingCleaner, {"inputs": {"motions": "motions"}}, tmp_path)
    assert ds.table("data").schema.remove_metadata().equals(schema.DIGRESSIONS)
    assert ds.table("edits").schema.remove_metadata().equals(schema.EDITS)
    assert len(ds.manifest["summary"]["clips"]) == 4


def test_a_spike_is_detected_and_repaired():
    m = synthetic_motion(30, fps=24.0, seed=1)
    rot = m.rotations.copy()
    rot[12, 5] = [0.0, 1.0, 0.0, 0.0]  # 180 degrees off
    bad = m.with_arrays(rotations=rot)
    c = SmoothingCleaner()
    assert c.detect(bad)[12, 5] > 0.5
    cleaned, edits = c.repair(bad)
    assert (12, 5) in set(zip(edits["frame"].to_pylist(), edits["joint"].to_pylist(), strict=True))
    out = c.detect_and_repair(bad, None, 3, None)
    assert out.digressions.filter(pa.compute.field("flagged")).num_rows >= 1


def test_a_broken_matcher_fails_the_checks():
    class Sloppy(DiagonalMatcher):
        """Returns matches without paths."""

        name = "sloppy"

        def match(self, query, space):
            r = super().match(query, space)
            return QueryMatches(r.start, r.end, r.cost, r.length, [])

    with pytest.raises((AssertionError, MocapflowError)):
        check_matcher(Sloppy)


def test_reference_index_is_exact_and_padded():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(20, 3)).astype(np.float32)
    idx = ReferenceIndex().build(x)
    dist, ids = idx.query(x[:2], 25, radius=1.0)
    assert ids.shape == (2, 25) and ids[0, 0] == 0 and dist[0, 0] == 0
    assert np.all((ids == -1) == np.isinf(dist))
    with pytest.raises(DataError):
        idx.query(np.zeros((1, 4)), 3)


def test_tables_follow_the_shared_schemas():
    space, query = synthetic_space()
    m = synthetic_motion(10)
    t = digression_table(np.zeros((10, m.n_joints)), m, 4)
    assert t.schema.equals(schema.DIGRESSIONS) and set(t["clip_id"].to_pylist()) == {4}
    assert edits_table(m, m).num_rows == 0
    with pytest.raises(DataError):
        digression_table(np.zeros((9, m.n_joints)), m)
    assert parse_query_spec("a.bvh:1-3").frames(30, 10) == (1, 3)
    assert space.memo("k", lambda: 1) == 1 and space.memo("k", lambda: 2) == 1
    with pytest.raises(MocapflowError):
        synthetic_space(index=False)[0].neighbors(query, 3)
