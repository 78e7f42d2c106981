"""Slow, obviously correct k-nearest-neighbour search (reference for indexes.kdtree)."""

from __future__ import annotations

import numpy as np


def knn(data, queries, k, radius=None, groups=None, frames=None, query_groups=None, query_frames=None, exclude=None):
    """Brute force: exact float64 distances, sorted by (distance, row id), padded with inf/-1."""
    data = np.asarray(data, np.float32).astype(np.float64)
    queries = np.atleast_2d(np.asarray(queries, np.float32)).astype(np.float64)
    n = len(data)
    out_d = np.full((len(queries), k), np.inf)
    out_i = np.full((len(queries), k), -1, np.int64)
    for r, q in enumerate(queries):
        d2 = np.zeros(n)
        for j in range(data.shape[1]):  # summed dimension by dimension, like the kernel
            d2 += (data[:, j] - q[j]) ** 2
        ok = np.ones(n, bool)
        if radius is not None:
            ok &= d2 <= radius**2
        if exclude is not None:
            ok &= ~((groups == query_groups[r]) & (np.abs(frames - query_frames[r]) <= exclude))
        rows = [i for i in np.lexsort((np.arange(n), d2)) if ok[i]][:k]
        out_d[r, : len(rows)] = np.sqrt(d2[rows])
        out_i[r, : len(rows)] = rows
    return out_d, out_i


def ckdtree_index_class():
    """scipy's cKDTree behind the Index contract (radius search capped at k, inclusive
    radius), a reference index for tests of components that take any Index."""
    from scipy.spatial import cKDTree

    from mocapflow.framework import Index

    class CKDTreeIndex(Index):
        """Test adapter: scipy's cKDTree behind the Index contract (radius search capped at k)."""

        name = "ckdtree_test"

        def build(self, features):
            self.tree_ = cKDTree(np.asarray(features, np.float64))
            return self

        def query(self, x, k, radius=None):
            ub = np.inf if radius is None else radius * (1 + 1e-9)
            d, i = self.tree_.query(np.asarray(x, np.float64), k=k, distance_upper_bound=ub)
            d, i = d.reshape(len(x), k), i.reshape(len(x), k)
            return d.astype(np.float32), np.where(np.isfinite(d), i, -1).astype(np.int64)

    return CKDTreeIndex
