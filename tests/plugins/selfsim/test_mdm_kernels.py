"""MDM cleaner kernels against their naive twins (tests/naive/cleaning.py)."""

from __future__ import annotations

import numpy as np
import pytest
from naive.cleaning import (
    brute_knn,
    naive_cdtw,
    naive_distance_function,
    naive_knn,
    naive_pose_distance,
    synthetic_walk,
)

from mocapflow.framework import quaternions as quat
from mocapflow.plugins.selfsim.paper import _mdm_kernels as kern
from mocapflow.plugins.selfsim.paper.knn import ContextTextures, knn_search
from mocapflow.plugins.selfsim.paper.motion_words import (
    DEFAULT_GROUPS,
    JointGroups,
    motion_texture,
    pose_distance,
    resolve_groups,
    source_word_starts,
    target_word_layout,
)


def _random_quats(rng, shape):
    return quat.normalize(rng.standard_normal(shape + (4,)))


def test_pose_distance_block_matches_naive():
    rng = np.random.default_rng(1)
    src, ctx = _random_quats(rng, (6, 7)), _random_quats(rng, (9, 7))
    mask = np.array([[1] * 7, [1, 1, 0, 0, 1, 0, 1], [0, 0, 0, 1, 0, 0, 0], [1, 1, 1, 0, 0, 0, 0]], np.uint8)
    drop = np.array([3, 1, 0, 2], np.int64)
    out = np.empty((4, 6, 9), np.float32)
    kern.pose_distance_block(src, ctx, mask, drop, out)
    for g in range(4):
        for i in range(6):
            for c in range(9):
                ref = naive_pose_distance(src[i], ctx[c], mask[g].astype(bool), int(drop[g]))
                assert out[g, i, c] == pytest.approx(ref, rel=1e-5, abs=1e-6)
                assert pose_distance(src[i], ctx[c], mask[g].astype(bool), int(drop[g])) == pytest.approx(ref, rel=1e-9)


def test_pose_distance_is_sign_invariant_and_zero_on_itself():
    rng = np.random.default_rng(2)
    q = _random_quats(rng, (3, 5))
    out = np.empty((1, 3, 3), np.float32)
    kern.pose_distance_block(q, -q, np.ones((1, 5), np.uint8), np.array([1], np.int64), out)
    assert np.allclose(np.diag(out[0]), 0.0, atol=1e-6)


@pytest.mark.parametrize("n,ln,r", [(15, 20, 2), (15, 15, 2), (5, 9, 1), (1, 4, 2), (4, 1, 2), (6, 8, 3), (2, 2, 1)])
def test_cdtw_matches_naive(n, ln, r):
    rng = np.random.default_rng(n * 100 + ln * 10 + r)
    for _ in range(5):
        d = rng.random((n + 3, ln + 4)).astype(np.float32)
        mean_ref, path_ref = naive_cdtw(d[2 : 2 + n, 1 : 1 + ln], r)
        m = max(ln, 1)
        work = np.empty((n, m, 2 * r + 1)), np.empty((n, m, 2 * r + 1), np.int64), np.empty((n, m, 2 * r + 1), np.int64)
        c, p = kern.cdtw(d, 2, 1, n, ln, r, *work)[:2]
        if r == 2:
            assert kern.cdtw_cost_r2(d, 2, 1, n, ln, np.empty((2, 5, m)), np.empty((2, 5, m), np.int64)) == (c, p)
        mean, path = kern.cdtw_path(d, 2, 1, n, ln, r)
        assert c / p == pytest.approx(mean_ref, rel=1e-12)
        assert mean == pytest.approx(mean_ref, rel=1e-12)
        assert len(path) == p
        # the path is a valid constrained path with the optimal mean cost
        assert tuple(path[0]) == (0, 0) and (path[-1, 0] == n - 1 or path[-1, 1] == ln - 1)
        steps = np.diff(path, axis=0)
        assert all(tuple(s) in {(1, 1), (0, 1), (1, 0)} for s in steps)
        assert d[2 + path[:, 0], 1 + path[:, 1]].astype(float).mean() == pytest.approx(mean_ref, rel=1e-12)


def test_cdtw_constant_costs_take_the_shortest_path():
    d = np.full((15, 20), 0.25, np.float32)
    mean, path = kern.cdtw_path(d, 0, 0, 15, 20, 2)
    assert mean == pytest.approx(0.25) and len(path) == 15
    assert kern.cdtw_cost_r2(d, 0, 0, 15, 20, np.empty((2, 5, 20)), np.empty((2, 5, 20), np.int64)) == (0.25 * 15, 15)
    assert naive_cdtw(d, 2)[0] == pytest.approx(0.25)


def test_cdtw_slope_constraint_limits_runs():
    rng = np.random.default_rng(3)
    d = rng.random((15, 20)).astype(np.float32)
    d[:, :] += 5.0
    d[0, :] = 0.0  # tempting to run along the first row
    _, path = kern.cdtw_path(d, 0, 0, 15, 20, 2)
    steps = [tuple(s) for s in np.diff(path, axis=0)]
    run = best = 0
    for a, b in zip(steps, steps[1:] + [None], strict=True):
        run = run + 1 if a != (1, 1) and a == b else 0
        best = max(best, run + (a != (1, 1)))
    assert best <= 2


def _toy_context(seed=0):
    rng = np.random.default_rng(seed)
    base = np.cumsum(rng.standard_normal((70, 4, 3)) * 0.15, axis=0)
    q = quat.normalize(np.concatenate([np.ones((70, 4, 1)), base], -1))
    clips = [q[:30], q[30:33], q[33:70]]  # a middle clip shorter than a word
    return q, clips


def test_lower_bound_never_exceeds_distance():
    _, clips = _toy_context(4)
    src = clips[0]
    ctx = ContextTextures.from_arrays(clips)
    groups = resolve_groups(("a", "b", "c", "d"), [("all", (), 1)])
    n, m, r = 6, 8, 2
    tlen, _ = target_word_layout(ctx.clip_lengths, n, m)
    starts = source_word_starts(len(src), n, 3)
    d = np.empty((1, len(src), len(ctx.q)), np.float32)
    kern.pose_distance_block(src, ctx.q, groups.mask.astype(np.uint8), groups.drop, d)
    w_rows = np.empty_like(d)
    kern.sliding_row_min(d, tlen, w_rows)
    v_cols = np.empty((1, len(starts), len(ctx.q)), np.float32)
    kern.word_column_min(d, starts, n, v_cols)
    lb = np.empty((1, len(starts), len(ctx.q)))
    kern.lower_bounds(w_rows, v_cols, starts, 0, n, tlen, r, lb)
    for w, s in enumerate(starts):
        f = naive_distance_function(src, ctx.q, ctx.clip_lengths, s, n, m, groups.mask[0], 1, r)
        ok = np.isfinite(f)
        assert np.all(np.isinf(lb[0, w][~ok]))
        assert np.all(lb[0, w][ok] <= f[ok] + 1e-9)
        assert np.any(lb[0, w][ok] > 0)  # a bound, not just zeros


@pytest.mark.parametrize("self_clip,r", [(0, 2), (-1, 2), (0, 3)])
def test_knn_pruned_equals_brute_and_naive(self_clip, r):
    _, clips = _toy_context(5)
    src = clips[0]
    ctx = ContextTextures.from_arrays(clips if self_clip == 0 else clips[1:])
    groups = resolve_groups(("a", "b", "c", "d"), [("all", (), 1), ("ab", ("a", "b"), 0)])
    n, m, k = 6, 8, 3
    starts = source_word_starts(len(src), n, 4)
    kw = dict(self_clip=self_clip, source_length=n, target_length=m, word_starts=starts, k=k, slope_run=r)
    fast = knn_search(src, ctx, groups, **kw)
    target, distance, n_dtw = brute_knn(src, ctx, groups, **kw)
    np.testing.assert_array_equal(fast.target, target)
    np.testing.assert_array_equal(fast.distance, distance)
    assert fast.n_dtw <= n_dtw
    for g in range(groups.n_groups):
        ref = naive_knn(
            src, ctx.q, ctx.clip_lengths, starts, n, m, groups.mask[g], int(groups.drop[g]), r, k, self_clip
        )
        for w, words in enumerate(ref):
            assert [t for t, _ in words] == [t for t in fast.target[g, w] if t >= 0]
            np.testing.assert_allclose([dd for _, dd in words], fast.distance[g, w][: len(words)], rtol=1e-9)


def test_knn_ties_on_a_constant_signal():
    q = quat.identity((40, 3))
    ctx = ContextTextures.from_arrays([q, q[:25]])
    groups = resolve_groups(("a", "b", "c"), [("all", (), 0)])
    starts = source_word_starts(40, 6, 5)
    kw = dict(self_clip=0, source_length=6, target_length=8, word_starts=starts, k=4, slope_run=2)
    fast = knn_search(q, ctx, groups, **kw)
    np.testing.assert_array_equal(fast.target, brute_knn(q, ctx, groups, **kw)[0])
    assert np.all(fast.distance[fast.target >= 0] == 0.0)


def test_knn_on_synthetic_walk_and_warp_shapes():
    tex = motion_texture(synthetic_walk(200))
    groups = resolve_groups(tex.joints, DEFAULT_GROUPS)
    starts = source_word_starts(tex.n_frames, 15, 5)
    ctx = ContextTextures.from_arrays([tex.q])
    fast = knn_search(tex.q, ctx, groups, self_clip=0, word_starts=starts)
    np.testing.assert_array_equal(fast.target, brute_knn(tex.q, ctx, groups, starts, self_clip=0)[0])
    assert fast.warped.shape == (5, len(starts), 5, 15, 24, 4)
    ok = fast.target >= 0
    assert np.allclose(np.linalg.norm(fast.warped[ok], axis=-1), 1.0)
    # no neighbour closer than N/2 frames to its own word
    assert np.all(np.abs(fast.target - starts[None, :, None])[ok] > 7)


def test_knn_equals_brute_force_on_real_clips():
    from conftest import corpus_path

    amc = pytest.importorskip("mocapflow.plugins.formats.asf_amc")
    root = corpus_path("cmu", "amc")
    take = amc.read_amc(root / "16" / "16_15.amc")
    other = amc.read_amc(root / "07" / "07_05.amc")
    tex = motion_texture(take)
    joints = tex.joints
    ctx = ContextTextures.from_arrays([tex.q, motion_texture(other, joints).q])
    groups = resolve_groups(joints, DEFAULT_GROUPS)
    starts = source_word_starts(tex.n_frames, 15, 5)
    fast = knn_search(tex.q, ctx, groups, self_clip=0, word_starts=starts)
    target, distance, n_dtw = brute_knn(tex.q, ctx, groups, starts, self_clip=0)
    np.testing.assert_array_equal(fast.target, target)
    np.testing.assert_array_equal(fast.distance, distance)
    assert fast.n_dtw < n_dtw


def test_resolve_groups_rejects_empty_group():
    from mocapflow.framework.errors import ConfigError

    with pytest.raises(ConfigError):
        resolve_groups(("root", "lhip"), [("arms", ("lelbow",), 1)])
    g = resolve_groups(("root", "lhip"), [("all", (), 3)])
    assert isinstance(g, JointGroups) and g.drop[0] == 1  # never drops every joint
