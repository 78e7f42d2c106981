"""Local subspace cells of the certified search: equal to the SVD definition, and admissible in float32."""

from __future__ import annotations

import numpy as np
import pytest
from naive.coarse import naive_block_dp, naive_boxes, naive_min_cells, naive_subspace_bounds
from naive.dtw import continues_of, naive_blocks, naive_through_cell
from test_exact_search import query_of
from test_sdtw import make_db

from mocapflow.plugins.similarity.search._coarse_kernels import block_boxes, coarse_bounds, subspace_bounds
from mocapflow.plugins.similarity.search._subspace_kernels import block_subspaces

# seed, clip lengths, query frames, rows per block, basis size, dimensions
CASES = [
    (0, [40, 1, 30, 12], 6, 4, 2, 3),
    (1, [80], 10, 16, 3, 5),
    (2, [5, 5, 5, 60], 3, 7, 2, 4),
    (3, [50, 50], 1, 3, 3, 6),
    (4, [7, 1, 1, 20], 12, 1, 2, 3),
    (5, [64, 30], 40, 16, 3, 15),
    (6, [33], 9, 2, 3, 15),
    (7, [41, 9], 20, 8, 1, 11),
]  # 6: a basis wider than a block's rank: zero rows


def bounds(q, x, cont, size, p, br=None, shrink=1.0):
    bstart, _, _, link = block_boxes(x, cont, size)
    cen, basis, alo, ahi, rad = block_subspaces(x, bstart, p)
    br = np.array([[0, len(link)]], np.int64) if br is None else br
    return subspace_bounds(np.ascontiguousarray(q.T), cen, basis, alo, ahi, rad, link, br, shrink)


@pytest.mark.parametrize("seed,lengths,m,size,p,dim", CASES)
def test_block_subspaces_are_orthonormal_and_enclose_the_rows(seed, lengths, m, size, p, dim):
    clip_id, frame, x = make_db(lengths, dim=dim, seed=seed)
    cont = continues_of(clip_id, frame)
    bstart, _, _, _ = block_boxes(x, cont, size)
    cen, basis, alo, ahi, rad = block_subspaces(x, bstart, p)
    block = naive_blocks(cont, size)
    for b in range(len(cen)):
        u = basis[b].astype(np.float64)
        assert not np.any(u[p:])  # three rows, p of them in use
        u = u[np.abs(u).sum(axis=1) > 0]
        np.testing.assert_allclose(u @ u.T, np.eye(len(u)), atol=1e-6)
        s = x[block == b].astype(np.float64) - cen[b]
        a = s @ u.T
        assert np.all(a >= alo[b, : len(u)]) and np.all(a <= ahi[b, : len(u)])
        assert np.sqrt(((s - a @ u) ** 2).sum(axis=1)).max() <= rad[b, 0]
        assert np.sqrt((s**2).sum(axis=1)).max() <= rad[b, 1]


@pytest.mark.parametrize("seed,lengths,m,size,p,dim", CASES)
def test_subspace_bounds_equal_naive_and_are_admissible(seed, lengths, m, size, p, dim):
    clip_id, frame, x = make_db(lengths, dim=dim, seed=seed)
    cont = continues_of(clip_id, frame)
    q = query_of(x, m, seed)
    shrink = 1.0 - 1e-4
    lb = bounds(q, x, cont, size, p, shrink=shrink)
    naive = naive_subspace_bounds(q, x, cont, size, p, shrink=shrink)
    np.testing.assert_allclose(lb, naive, rtol=2e-4, atol=1e-5)  # the kernel's float32 margins
    _, _, _, link = naive_boxes(x, cont, size)
    tightest = naive_block_dp(naive_min_cells(q, x, cont, size), link)
    assert np.all(lb <= tightest)  # never above the bound of exact cells ..
    block = naive_blocks(cont, size)
    through = naive_through_cell(q, x, cont).min(axis=0)
    assert np.all(lb[block] <= through)  # .. nor above the best path through any row of the block
    tau = float(np.quantile(through, 0.4))
    alive = lb <= tau
    edge = np.diff(np.r_[0, alive.astype(np.int8), 0])
    br = np.stack([np.flatnonzero(edge == 1), np.flatnonzero(edge == -1)], axis=1).astype(np.int64)
    sub = bounds(q, x, cont, size, p, br, shrink)
    np.testing.assert_allclose(sub, naive_subspace_bounds(q, x, cont, size, p, br, shrink), rtol=2e-4, atol=1e-5)
    assert np.all(sub[block[through <= tau]] <= tau) and np.all(np.isinf(sub[~alive]))


@pytest.mark.parametrize("p", [1, 2, 3])
@pytest.mark.parametrize("offset", [0.0, 1e3])
def test_subspace_bounds_admissible_where_float32_cancels(p, offset):
    # blocks far from the origin with a tiny spread, queries that are database rows themselves:
    # the true cost of those paths is 0, so any rounding of the bound upwards would show
    clip_id, frame, x = make_db([48, 17, 40], dim=15, seed=11)
    x = (x * np.float32(1e-3) + np.float32(offset)).astype(np.float32)
    cont = continues_of(clip_id, frame)
    for a, m in [(3, 9), (20, 16), (70, 30)]:
        q = x[a : a + m].copy()
        for size in (4, 16):
            lb = bounds(q, x, cont, size, p)
            block = naive_blocks(cont, size)
            assert np.all(lb[block[a : a + m]] == 0.0)
            through = naive_through_cell(q, x, cont).min(axis=0)
            assert np.all(lb[block] <= through)


def test_subspace_cells_tighter_than_boxes_on_motion_like_rows():
    # smooth rows (a random walk): along the few directions a block spans, the subspace cell
    # is at least as tight as the box on most blocks, and tighter in total
    clip_id, frame, x = make_db([400], dim=15, seed=3)
    cont = continues_of(clip_id, frame)
    q = query_of(x, 30, 3)
    bstart, lo, hi, link = block_boxes(x, cont, 16)
    box = coarse_bounds(np.ascontiguousarray(q.T), lo, hi, link, np.array([[0, len(lo)]], np.int64), 1.0)
    sub = bounds(q, x, cont, 16, 3)
    assert sub.sum() > box.sum()


def test_block_subspaces_on_threads_equal_one_thread():
    """The cells are computed in chunks on numba's threads: the same values as on one."""
    import numba

    clip_id, frame, x = make_db([3000, 1, 2500], dim=15, seed=9)
    bstart = block_boxes(x, continues_of(clip_id, frame), 4)[0]
    width = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = block_subspaces(x, bstart, 3)
    finally:
        numba.set_num_threads(width)
    for a, b in zip(one, block_subspaces(x, bstart, 3), strict=True):
        np.testing.assert_array_equal(a, b)
