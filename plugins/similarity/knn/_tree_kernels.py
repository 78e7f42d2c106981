"""Numba kernels that build the float32 kd-tree and derive what its searches need (no
validation: :mod:`.kdtree` validates): sliding-midpoint splits into buckets of at most
``leafsize`` points (Arya & Mount's ANN), the tight bounding box of every node's points
(derived from the stored tree, never saved), the tree's depth.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def _partition(data: np.ndarray, perm: np.ndarray, s: int, e: int, dim: int, cut: float) -> int:
    """Reorder ``perm[s:e]`` into rows with ``data[:, dim] < cut`` then the others; returns
    the first position of the second part."""
    i, k = s, e - 1
    while i <= k:
        if data[perm[i], dim] < cut:
            i += 1
        else:
            perm[i], perm[k] = perm[k], perm[i]
            k -= 1
    return i


@njit(cache=True)
def build_tree(
    data: np.ndarray, leafsize: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sliding-midpoint kd-tree over ``data (n, d)`` float32.

    Returns ``perm`` (row of the input at each tree position) and the node arrays
    ``start, end, left, right, split_dim, split_val`` (leaves have ``left == -1``).
    """
    n, d = data.shape
    perm = np.arange(n).astype(np.int64)
    cap = 2 * n + 1
    start = np.empty(cap, np.int64)
    end = np.empty(cap, np.int64)
    left = np.full(cap, -1, np.int64)
    right = np.full(cap, -1, np.int64)
    sdim = np.zeros(cap, np.int32)
    sval = np.zeros(cap, np.float32)
    start[0] = 0
    end[0] = n
    n_nodes = 1
    stack = np.empty(cap, np.int64)
    stack[0] = 0
    top = 1
    lo = np.empty(d, np.float32)
    hi = np.empty(d, np.float32)
    while top > 0:
        top -= 1
        node = stack[top]
        s, e = start[node], end[node]
        if e - s <= leafsize:
            continue
        for j in range(d):
            lo[j] = np.inf
            hi[j] = -np.inf
        for i in range(s, e):
            row = perm[i]
            for j in range(d):
                v = data[row, j]
                if v < lo[j]:
                    lo[j] = v
                if v > hi[j]:
                    hi[j] = v
        dim = 0
        spread = hi[0] - lo[0]
        for j in range(1, d):
            if hi[j] - lo[j] > spread:
                spread = hi[j] - lo[j]
                dim = j
        if spread <= 0.0:  # all points identical: one (large) bucket
            continue
        cut = np.float32(0.5 * (np.float64(lo[dim]) + np.float64(hi[dim])))
        mid = _partition(data, perm, s, e, dim, cut)
        if mid == s:  # slide the cut down to the minimum: one side gets the minimum points
            cut = hi[dim]
            for t in range(s, e):
                v = data[perm[t], dim]
                if v > lo[dim] and v < cut:
                    cut = v
            mid = _partition(data, perm, s, e, dim, cut)
        elif mid == e:  # cannot happen for cut <= hi with the < rule, kept for safety
            continue
        sdim[node] = dim
        sval[node] = cut
        left[node] = n_nodes
        start[n_nodes], end[n_nodes] = s, mid
        right[node] = n_nodes + 1
        start[n_nodes + 1], end[n_nodes + 1] = mid, e
        stack[top] = n_nodes
        stack[top + 1] = n_nodes + 1
        top += 2
        n_nodes += 2
    return (
        perm,
        start[:n_nodes].copy(),
        end[:n_nodes].copy(),
        left[:n_nodes].copy(),
        right[:n_nodes].copy(),
        sdim[:n_nodes].copy(),
        sval[:n_nodes].copy(),
    )


@njit(cache=True)
def node_boxes(
    data: np.ndarray, start: np.ndarray, end: np.ndarray, left: np.ndarray, right: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Tight bounding box ``(lo, hi)`` of each node's points, shape (n_nodes, d) float32.

    Derived from the stored tree (children are created after their parent, so a reverse
    sweep merges children into parents): one pass over the points, O(n d).
    """
    n_nodes = left.shape[0]
    d = data.shape[1]
    lo = np.empty((n_nodes, d), np.float32)
    hi = np.empty((n_nodes, d), np.float32)
    for node in range(n_nodes - 1, -1, -1):
        if left[node] < 0:
            for j in range(d):
                lo[node, j] = np.inf
                hi[node, j] = -np.inf
            for t in range(start[node], end[node]):
                for j in range(d):
                    v = data[t, j]
                    if v < lo[node, j]:
                        lo[node, j] = v
                    if v > hi[node, j]:
                        hi[node, j] = v
        else:
            a, b = left[node], right[node]
            for j in range(d):
                lo[node, j] = min(lo[a, j], lo[b, j])
                hi[node, j] = max(hi[a, j], hi[b, j])
    return lo, hi


@njit(cache=True)
def tree_depth(left: np.ndarray, right: np.ndarray) -> int:
    """Depth of the deepest node (children are always created after their parent)."""
    depth = np.zeros(left.shape[0], np.int64)
    best = 0
    for node in range(left.shape[0]):
        if left[node] >= 0:
            depth[left[node]] = depth[node] + 1
            depth[right[node]] = depth[node] + 1
            if depth[node] + 1 > best:
                best = depth[node] + 1
    return best
