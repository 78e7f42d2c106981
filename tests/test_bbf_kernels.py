"""benchmarks/_bbf_kernels.py (a design measured for issue 13 §3): best-bin-first search against brute force."""
from __future__ import annotations

import sys

import numpy as np
import pytest
from conftest import REPO

from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex

sys.path.insert(0, str(REPO / "benchmarks"))
from _bbf_kernels import bbf_query


def _tree(x, leaf):
    tree = KDTreeIndex(method="kdtree", workers=1, leafsize=leaf).build(x)
    data, perm, start, end, left, right, _, _, blo, bhi = tree._tree_args()[0][:10]
    return data, perm, start, end, left, right, blo, bhi


@pytest.mark.parametrize("seed, leaf, k", [(0, 4, 1), (1, 8, 17), (2, 64, 50), (3, 16, 300)])
def test_unlimited_budget_is_exact(seed, leaf, k):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(300, 5)).astype(np.float32)
    arrays = _tree(x, leaf)
    for q in rng.normal(size=(10, 5)):
        got = bbf_query(q, k, 10**9, *arrays)
        d = ((x.astype(np.float64) - q) ** 2).sum(1)
        np.testing.assert_array_equal(np.sort(got), np.sort(np.argsort(d, kind="stable")[:k]))


def test_budget_returns_distinct_rows_no_closer_than_the_truth():
    rng = np.random.default_rng(4)
    x = rng.normal(size=(2000, 6)).astype(np.float32)
    arrays = _tree(x, 16)
    k = 40
    recall = []
    for q in rng.normal(size=(20, 6)):
        got = bbf_query(q, k, 64, *arrays)
        assert len(set(got.tolist())) == k and got.min() >= 0 and got.max() < len(x)
        d = ((x.astype(np.float64) - q) ** 2).sum(1)
        truth = np.argsort(d, kind="stable")[:k]
        assert d[got].max() >= d[truth].max()  # an approximation never beats the exact k-th distance
        recall.append(len(set(got.tolist()) & set(truth.tolist())) / k)
    assert np.mean(recall) < 1.0  # 64 points scanned of 2,000 cannot find every neighbour
