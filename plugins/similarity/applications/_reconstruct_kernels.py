"""Numba kernels of the reconstruction (no validation: :mod:`.reconstruct` validates).

:func:`map_pose`: the local linear model of the neighbours (:func:`.reconstruct._local_model`),
the MAP pose of markers + prior + smoothness and the heading, alternated. Its slow,
obviously correct NumPy twin is ``_map_pose_numpy`` in ``tests/plugins/similarity/test_reconstruct.py``.

:func:`swivel_path`: the Viterbi path through the knee/elbow swivel states of a take
(:func:`.reconstruct_sides.consistent_sides`); its twin, scoring every path, is
``_swivel_path_numpy`` in ``tests/plugins/similarity/test_reconstruct_sides.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _yaw(model: np.ndarray, observed: np.ndarray) -> float:
    s = 0.0
    c = 0.0
    for i in range(model.shape[0]):
        s += observed[i, 0] * model[i, 2] - observed[i, 2] * model[i, 0]
        c += observed[i, 0] * model[i, 0] + observed[i, 2] * model[i, 2]
    yaw: float = np.arctan2(s, c)
    return yaw


@njit(cache=True)
def map_pose(
    nb: np.ndarray,
    sel: np.ndarray,
    rel: np.ndarray,
    theta: float,
    pred: np.ndarray,
    has_pred: bool,
    w_m: float,
    w_s: float,
    alternations: int,
) -> tuple[np.ndarray, float]:
    """MAP pose (D,) and heading of neighbours ``nb`` (K, D) float64 for markers ``rel``
    (M, 3) relative to the root; ``sel`` (3M,) marker columns; ``pred`` (D,) the prediction."""
    k, d = nb.shape
    mu = np.zeros(d)
    for i in range(k):
        mu += nb[i]
    mu /= k
    x = nb - mu
    xs = np.empty((k, sel.shape[0]))
    for j in range(sel.shape[0]):
        xs[:, j] = x[:, sel[j]]
    lhs = w_m * (xs @ xs.T)
    if has_pred:
        lhs += w_s * (x @ x.T)
    for i in range(k):
        lhs[i, i] += max(k - 1, 1)
    m = rel.shape[0]
    obs = np.empty(3 * m)
    guess = mu.copy()
    for _ in range(alternations):
        c, s = np.cos(-theta), np.sin(-theta)
        for i in range(m):
            obs[3 * i] = c * rel[i, 0] + s * rel[i, 2]
            obs[3 * i + 1] = rel[i, 1]
            obs[3 * i + 2] = -s * rel[i, 0] + c * rel[i, 2]
        r = np.empty(3 * m)
        for j in range(3 * m):
            r[j] = obs[j] - mu[sel[j]]
        rhs = w_m * (xs @ r)
        if has_pred:
            rhs += w_s * (x @ (pred - mu))
        a = np.linalg.solve(lhs, rhs)
        guess = mu + x.T @ a
        model = np.empty((m, 3))
        for j in range(3 * m):
            model[j // 3, j % 3] = guess[sel[j]]
        theta = _yaw(model, rel)
    return guess, theta


@njit(cache=True)
def swivel_path(unary: np.ndarray, pts: np.ndarray, w_t: float) -> np.ndarray:
    """Viterbi path (T,) int64 through ``S`` candidate states per frame: ``unary`` (T, S)
    costs, ``pts`` (T, S, 3) each state's joint position, transition cost
    ``w_t * |pts[t, s] - pts[t - 1, r]|^2``; the path of least total cost (ties: lowest state)."""
    t_len, n_s = unary.shape
    path = np.zeros(t_len, np.int64)
    if t_len == 0:
        return path
    back = np.zeros((t_len, n_s), np.int64)
    cost = unary[0].copy()
    for t in range(1, t_len):
        new = np.empty(n_s)
        for s in range(n_s):
            best, arg = np.inf, 0
            for r in range(n_s):
                d = 0.0
                for a in range(3):
                    e = pts[t, s, a] - pts[t - 1, r, a]
                    d += e * e
                c = cost[r] + w_t * d
                if c < best:
                    best, arg = c, r
            new[s] = best + unary[t, s]
            back[t, s] = arg
        cost = new
    s = 0
    for r in range(1, n_s):
        if cost[r] < cost[s]:
            s = r
    path[t_len - 1] = s
    for t in range(t_len - 1, 0, -1):
        s = back[t, s]
        path[t - 1] = s
    return path
