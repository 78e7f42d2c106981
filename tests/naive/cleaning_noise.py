"""Slow, obviously correct reference for the bounded noise repair of the calibrated cleaner
(:mod:`mocapflow.plugins.selfsim.noise`, session 6 round 2).

Scalar loops and quaternion arithmetic written out here (rotation vector via axis and angle),
independent of :mod:`mocapflow.framework.quaternions`.
"""
from __future__ import annotations

import math

import numpy as np

from naive.cleaning_holds import _conj, _mul, _slerp


def _log(q):
    w, x, y, z = q
    if w < 0:
        w, x, y, z = -w, -x, -y, -z
    s = math.sqrt(x * x + y * y + z * z)
    if s < 1e-12:
        return [2 * x, 2 * y, 2 * z]
    ang = 2 * math.atan2(s, w)
    return [x / s * ang, y / s * ang, z / s * ang]


def _exp(v):
    ang = math.sqrt(sum(c * c for c in v))
    if ang < 1e-12:
        return [1.0, v[0] / 2, v[1] / 2, v[2] / 2]
    k = math.sin(ang / 2) / ang
    return [math.cos(ang / 2), k * v[0], k * v[1], k * v[2]]


def _angle(a, b):
    d = abs(sum(x * y for x, y in zip(a, b)))
    return 2 * math.acos(min(1.0, d))


def _unit(q):
    n = math.sqrt(sum(c * c for c in q))
    return [c / n for c in q]


def naive_noise_repair(q: np.ndarray, mean_q: np.ndarray, mask: np.ndarray, half: int, factor: float,
                       floor: float = math.radians(1.0)):
    """Per joint: d_t = log(mean_t^-1 q_t); s_t = mean of d over [t-half, t+half] (clipped);
    amp_t = sqrt(mean over the window of |d - s|^2); cap = max(amp - factor * max(median_t amp, floor), 0);
    a masked cell moves from q_t toward mean_t exp(s_t) by at most cap along the geodesic, kept
    only when that is strictly nearer mean_t."""
    t_count, m = mask.shape
    new = np.array(q, float)
    edited = np.zeros((t_count, m), bool)
    for j in range(m):
        d = [_log(_unit(_mul(_conj(list(mean_q[t, j])), list(q[t, j])))) for t in range(t_count)]
        win = [range(max(0, t - half), min(t_count, t + half + 1)) for t in range(t_count)]
        s = [[sum(d[k][c] for k in w) / len(w) for c in range(3)] for w in win]
        r2 = [sum((d[t][c] - s[t][c]) ** 2 for c in range(3)) for t in range(t_count)]
        amp = [math.sqrt(sum(r2[k] for k in w) / len(w)) for w in win]
        null = max(float(np.median(amp)), floor)
        for t in range(t_count):
            cap = max(amp[t] - factor * null, 0.0)
            if not mask[t, j] or cap <= 0:
                continue
            target = _unit(_mul(list(mean_q[t, j]), _exp(s[t])))
            move = _angle(q[t, j], target)
            if move <= 0:
                continue
            cand = _unit(_slerp(list(q[t, j]), target, min(1.0, cap / move)))
            if _angle(cand, mean_q[t, j]) < _angle(q[t, j], mean_q[t, j]) - 1e-9:
                new[t, j] = cand
                edited[t, j] = True
    return new, edited


def naive_word_null(res, half: int) -> np.ndarray:
    """Per cell (f, j): the words covering f, the one whose centre is nearest (first on ties),
    the first joint group holding j, and over that group's valid neighbours the median of
    each neighbour's amplitude (as in :func:`naive_noise_repair`) against T̄ at f."""
    mean_q = res.mean_texture
    t_count, m = mean_q.shape[:2]
    out = np.full((t_count, m), np.nan)
    neigh = res.neighbours[0]
    n = neigh.warped.shape[3]
    for f in range(t_count):
        best = None
        for w, s in enumerate(neigh.starts):
            if s <= f < s + n and (best is None or abs(s + (n - 1) / 2 - f) < abs(neigh.starts[best] + (n - 1) / 2 - f)):
                best = w
        if best is None:
            continue
        s0 = int(neigh.starts[best])
        for j in range(m):
            gs = [g for g in range(neigh.groups.mask.shape[0]) if neigh.groups.mask[g, j]]
            if not gs:
                continue
            amps = []
            for k in range(neigh.warped.shape[2]):
                if neigh.target[gs[0], best, k] < 0:
                    continue
                word = neigh.warped[gs[0], best, k][:, j:j + 1]
                ref = mean_q[s0:s0 + n, j:j + 1]
                d = [_log(_unit(_mul(_conj(list(ref[t, 0])), list(word[t, 0])))) for t in range(n)]
                win = [range(max(0, t - half), min(n, t + half + 1)) for t in range(n)]
                sm = [[sum(d[i][c] for i in wn) / len(wn) for c in range(3)] for wn in win]
                r2 = [sum((d[t][c] - sm[t][c]) ** 2 for c in range(3)) for t in range(n)]
                amps.append(math.sqrt(sum(r2[i] for i in win[f - s0]) / len(win[f - s0])))
            if amps:
                out[f, j] = float(np.median(amps))
    return out
