"""benchmarks/_ceiling_kernels.py: the oracle of the certified search's ceiling against the full matrices."""
from __future__ import annotations

import sys

import numpy as np
import pytest
from conftest import REPO
from naive.dtw import continues_of, naive_subsequence_dtw, naive_through_cell

sys.path.insert(0, str(REPO / "benchmarks"))
from _ceiling_kernels import through_cell_rows


@pytest.mark.parametrize("seed, m, integer", [(0, 1, False), (1, 5, False), (2, 9, True), (3, 17, False)])
def test_through_cell_rows_matches_full_matrices(seed, m, integer):
    rng = np.random.default_rng(seed)
    n, d = 70, 3
    clip_id = np.repeat(np.arange(5), [1, 12, 30, 2, 25])
    frame = np.concatenate([np.arange(c) for c in (1, 12, 30, 2, 25)])
    frame[50] += 3  # a gap inside clip 2: rows 49 -> 50 do not continue
    x = rng.normal(size=(n, d))
    q = rng.normal(size=(m, d))
    if integer:  # ties everywhere
        x, q = np.round(2 * x), np.round(2 * q)
    x = x.astype(np.float32)
    q = q.astype(np.float32).astype(np.float64)
    cont = continues_of(clip_id, frame)
    ref = naive_through_cell(q, x, cont)
    D, _, _ = naive_subsequence_dtw(q, x, cont)
    tau = float(np.quantile(ref.min(axis=0), 0.3))
    row_min, cells, end_cost = through_cell_rows(q, x, cont, tau)
    np.testing.assert_allclose(row_min, ref.min(axis=0), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(end_cost, D[-1], rtol=1e-12, atol=1e-12)
    # the counts near tau may differ by rounding only where a cell's value is within 1e-9 of it
    close = np.abs(ref - tau) <= 1e-9 * max(tau, 1.0)
    lo, hi = ((ref <= tau) & ~close).sum(axis=0), ((ref <= tau) | close).sum(axis=0)
    assert np.all((lo <= cells) & (cells <= hi))
    assert 0 < (row_min <= tau).sum() < n
