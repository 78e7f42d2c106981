"""Slow, obviously correct references for the MDM cleaner kernels, and synthetic motions.

* :func:`naive_pose_distance` - eq. 1 with Python loops;
* :func:`naive_cdtw` - the constrained DTW of the paper's Appendix by explicit enumeration
  of DP states with dictionaries (no shared work arrays);
* :func:`naive_knn` - every word distance, local minima, exclusion, K smallest;
* :func:`brute_knn` - the same brute force compiled (every DTW computed), fast enough for
  real clips: the reference of the pruned KNN search;
* :func:`synthetic_skeleton` / :func:`synthetic_walk` - a small canonical skeleton and a
  seeded gait-like motion so unit tests need no corpus.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from mocapflow.framework import quaternions as quat
from mocapflow.framework.joints import CANONICAL_JOINTS
from mocapflow.framework.motion import Motion
from mocapflow.framework.skeleton import Skeleton
from mocapflow.plugins.selfsim.paper import _mdm_kernels as kern


def naive_pose_distance(a: np.ndarray, b: np.ndarray, mask: np.ndarray, drop: int) -> float:
    """Eq. 1 between two poses (m, 4): squared half-angles, the ``drop`` largest left out."""
    terms = []
    for k in range(len(a)):
        if mask[k]:
            d = min(1.0, abs(float(np.dot(a[k], b[k]))))
            terms.append(math.acos(d) ** 2)
    terms.sort()
    return float(sum(terms[: len(terms) - drop]))


def naive_cdtw(cost: np.ndarray, r: int) -> tuple[float, list[tuple[int, int]]]:
    """Constrained DTW on an (N, L) cost matrix; returns (mean cost, path).

    States are (i, j, kind, run): kind 'd' (diagonal/start), 'h' (target advanced), 'v'
    (source advanced); a run of 'h' or 'v' is at most ``r`` long. The path ends at the first
    cell of the last row or last column; the path with the lowest cumulative cost wins (ties:
    the shorter one).
    """
    n, ln = cost.shape
    best: dict[tuple[int, int, str, int], tuple[float, int, tuple | None]] = {
        (0, 0, "d", 0): (float(cost[0, 0]), 1, None)
    }

    def terminal(i: int, j: int) -> bool:
        return i == n - 1 or j == ln - 1

    def relax(key, value):
        old = best.get(key)
        if old is None or value[0] < old[0] or (value[0] == old[0] and value[1] < old[1]):
            best[key] = value

    for i in range(n):
        for j in range(ln):
            for key in [k for k in list(best) if k[0] == i and k[1] == j]:
                c, length, _ = best[key]
                if terminal(i, j):
                    continue
                _, _, kind, run = key
                relax((i + 1, j + 1, "d", 0), (c + float(cost[i + 1, j + 1]), length + 1, key))
                if kind != "h" or run < r:
                    relax((i, j + 1, "h", run + 1 if kind == "h" else 1), (c + float(cost[i, j + 1]), length + 1, key))
                if kind != "v" or run < r:
                    relax((i + 1, j, "v", run + 1 if kind == "v" else 1), (c + float(cost[i + 1, j]), length + 1, key))
    ends = [(v[0], v[1], k) for k, v in best.items() if terminal(k[0], k[1])]
    c, length, key = min(ends, key=lambda e: (e[0], e[1]))
    path = []
    while key is not None:
        path.append((key[0], key[1]))
        key = best[key][2]
    return c / length, path[::-1]


def naive_distance_function(
    src: np.ndarray, ctx: np.ndarray, clip_lengths, s: int, n: int, m: int, mask: np.ndarray, drop: int, r: int
) -> np.ndarray:
    """Word distance of the source word at ``s`` against every context start (inf: none)."""
    out = np.full(len(ctx), np.inf)
    off = 0
    for length in clip_lengths:
        for t in range(off, off + length):
            left = off + length - t
            if left < n:
                continue
            ln = min(m, left)
            cost = np.array(
                [[naive_pose_distance(src[s + i], ctx[t + j], mask, drop) for j in range(ln)] for i in range(n)],
                dtype=np.float32,
            )
            out[t] = naive_cdtw(cost, r)[0]
        off += length
    return out


def naive_knn(src, ctx, clip_lengths, starts, n, m, mask, drop, r, k, self_clip=-1, radius=None):
    """Brute-force KNN per source word: [(start, distance), ...] for each word."""
    radius = n // 2 if radius is None else radius
    offs = np.concatenate([[0], np.cumsum(clip_lengths)])
    clip_of = np.repeat(np.arange(len(clip_lengths)), clip_lengths)
    result = []
    for s in starts:
        f = naive_distance_function(src, ctx, clip_lengths, s, n, m, mask, drop, r)
        cands = []
        for t in range(len(ctx)):
            if not np.isfinite(f[t]):
                continue
            if self_clip >= 0 and clip_of[t] == self_clip and abs(t - (offs[self_clip] + s)) <= radius:
                continue
            left_ok = t == 0 or clip_of[t - 1] != clip_of[t] or not np.isfinite(f[t - 1]) or f[t] < f[t - 1]
            right_ok = (
                t + 1 >= len(ctx) or clip_of[t + 1] != clip_of[t] or not np.isfinite(f[t + 1]) or f[t] <= f[t + 1]
            )
            if left_ok and right_ok:
                cands.append((f[t], t))
        cands.sort()
        result.append([(t, d) for d, t in cands[:k]])
    return result


@njit(cache=True, parallel=True)
def knn_brute(d, starts, row0, n, tlen, clip_of, self_clip, self_off, radius, r, k, out_t, out_d):  # pragma: no cover
    """Reference KNN: the word distance at every target start, its local minima (within each
    clip), those farther than ``radius`` frames from the source word, the ``k`` smallest.

    ``self_clip`` is the source clip's position in the context (-1: not in it) and
    ``self_off`` the context frame of its first frame. d (G, rows, C) float32; out_t
    (G, S, k) int64 (-1 = none), out_d (G, S, k) float64 (inf = none).
    """
    n_g = d.shape[0]
    n_w = starts.shape[0]
    n_c = tlen.shape[0]
    m = 1
    for t in range(n_c):
        m = max(m, tlen[t])
    for gw in prange(n_g * n_w):
        g = gw // n_w
        w = gw % n_w
        dg = d[g]
        nr = 0 if r == 2 else n  # cdtw's work arrays, for r != 2 only
        cum = np.empty((nr, m, 2 * r + 1))
        plen = np.empty((nr, m, 2 * r + 1), np.int64)
        back = np.empty((nr, m, 2 * r + 1), np.int64)
        cost2 = np.empty((2, 5, m))
        plen2 = np.empty((2, 5, m), np.int64)
        f = np.full(n_c, np.inf)
        i0 = starts[w] - row0
        for t in range(n_c):
            if tlen[t] > 0:
                if r == 2:
                    c, p = kern.cdtw_cost_r2(dg, i0, t, n, tlen[t], cost2, plen2)
                else:
                    c, p, _, _, _ = kern.cdtw(dg, i0, t, n, tlen[t], r, cum, plen, back)
                f[t] = c / p
        best_d = np.full(k, np.inf)
        best_t = np.full(k, np.int64(2**62))
        self_pos = self_off + starts[w]
        for t in range(n_c):
            if tlen[t] == 0 or kern._excluded(t, clip_of, self_clip, self_pos, radius):
                continue
            if t > 0 and tlen[t - 1] > 0 and clip_of[t - 1] == clip_of[t] and not f[t] < f[t - 1]:
                continue
            if t + 1 < n_c and tlen[t + 1] > 0 and clip_of[t + 1] == clip_of[t] and not f[t] <= f[t + 1]:
                continue
            kern._insert_topk(best_d, best_t, k, f[t], t)
        for a in range(k):
            out_d[g, w, a] = best_d[a]
            out_t[g, w, a] = best_t[a] if best_d[a] < np.inf else -1


def brute_knn(
    source_q,
    context,
    groups,
    word_starts,
    self_clip=-1,
    source_length=15,
    target_length=20,
    k=5,
    slope_run=2,
    radius=None,
):
    """:func:`knn_search`'s neighbours by brute force: (target (G, S, K), distance (G, S, K), DTWs)."""
    from mocapflow.plugins.selfsim.paper.motion_words import target_word_layout

    n, starts = source_length, np.asarray(word_starts, np.int64)
    radius = n // 2 if radius is None else radius
    tlen, clip_of = target_word_layout(context.clip_lengths, n, target_length)
    self_off = int(context.offsets[self_clip]) if self_clip >= 0 else 0
    g_count = groups.n_groups
    d = np.empty((g_count, len(source_q), len(context.q)), np.float32)
    kern.pose_distance_block(
        np.ascontiguousarray(source_q, dtype=np.float64),
        context.q,
        groups.mask.astype(np.uint8),
        groups.drop.astype(np.int64),
        d,
    )
    out_t = np.empty((g_count, len(starts), k), np.int64)
    out_d = np.empty((g_count, len(starts), k))
    knn_brute(d, starts, 0, n, tlen, clip_of, self_clip, self_off, radius, slope_run, k, out_t, out_d)
    return out_t, out_d, g_count * len(starts) * int((tlen > 0).sum())


# --- synthetic motions ------------------------------------------------------------------
_PARENT = {
    "root": None,
    "lhip": "root",
    "lknee": "lhip",
    "lankle": "lknee",
    "ltoes": "lankle",
    "rhip": "root",
    "rknee": "rhip",
    "rankle": "rknee",
    "rtoes": "rankle",
    "lowerback": "root",
    "upperback": "lowerback",
    "chest": "upperback",
    "neck": "chest",
    "head": "neck",
    "headtop": "head",
    "lclavicle": "chest",
    "lshoulder": "lclavicle",
    "lelbow": "lshoulder",
    "lwrist": "lelbow",
    "lfingers": "lwrist",
    "rclavicle": "chest",
    "rshoulder": "rclavicle",
    "relbow": "rshoulder",
    "rwrist": "relbow",
    "rfingers": "rwrist",
}
_OFFSET = {
    "root": (0, 0, 0),
    "lhip": (0.1, -0.05, 0),
    "lknee": (0, -0.42, 0),
    "lankle": (0, -0.42, 0),
    "ltoes": (0, -0.05, 0.12),
    "rhip": (-0.1, -0.05, 0),
    "rknee": (0, -0.42, 0),
    "rankle": (0, -0.42, 0),
    "rtoes": (0, -0.05, 0.12),
    "lowerback": (0, 0.1, 0),
    "upperback": (0, 0.12, 0),
    "chest": (0, 0.12, 0),
    "neck": (0, 0.15, 0),
    "head": (0, 0.08, 0),
    "headtop": (0, 0.15, 0),
    "lclavicle": (0.05, 0.1, 0),
    "lshoulder": (0.12, 0, 0),
    "lelbow": (0.28, 0, 0),
    "lwrist": (0.25, 0, 0),
    "lfingers": (0.08, 0, 0),
    "rclavicle": (-0.05, 0.1, 0),
    "rshoulder": (-0.12, 0, 0),
    "relbow": (-0.28, 0, 0),
    "rwrist": (-0.25, 0, 0),
    "rfingers": (-0.08, 0, 0),
}


def synthetic_skeleton() -> Skeleton:
    """A 25-joint skeleton named by the canonical vocabulary (rest pose faces +z)."""
    names = list(CANONICAL_JOINTS)
    parents = [-1 if _PARENT[j] is None else names.index(_PARENT[j]) for j in names]
    return Skeleton(
        tuple(names),
        np.array(parents),
        np.array([_OFFSET[j] for j in names], float),
        canonical={j: i for i, j in enumerate(names)},
        name="synthetic",
    )


def synthetic_walk(
    n_frames: int = 480, fps: float = 24.0, seed: int = 0, period: float = 1.0, name: str = "walk"
) -> Motion:
    """A gait-like motion: legs, arms and spine swing with one period, small seeded variations."""
    rng = np.random.default_rng(seed)
    skel = synthetic_skeleton()
    t = np.arange(n_frames) / fps
    # slowly varying phase speed and amplitude so cycles are similar but not identical
    speed = 1.0 + 0.05 * np.sin(2 * np.pi * t / 7.3 + rng.uniform(0, 6))
    phase = 2 * np.pi * np.cumsum(speed) / fps / period
    amp = 1.0 + 0.08 * np.sin(2 * np.pi * t / 5.1 + rng.uniform(0, 6))
    ax_x = np.array([1.0, 0, 0])
    ax_y = np.array([0, 1.0, 0])
    ax_z = np.array([0, 0, 1.0])
    swing = {
        "lhip": (ax_x, 0.5, 0.0),
        "rhip": (ax_x, 0.5, np.pi),
        "lknee": (ax_x, 0.6, 1.2),
        "rknee": (ax_x, 0.6, 1.2 + np.pi),
        "lankle": (ax_x, 0.25, 0.5),
        "rankle": (ax_x, 0.25, 0.5 + np.pi),
        "ltoes": (ax_x, 0.2, 2.0),
        "rtoes": (ax_x, 0.2, 2.0 + np.pi),
        "lshoulder": (ax_x, 0.45, np.pi),
        "rshoulder": (ax_x, 0.45, 0.0),
        "lelbow": (ax_x, 0.3, np.pi + 0.6),
        "relbow": (ax_x, 0.3, 0.6),
        "lowerback": (ax_y, 0.1, 0.0),
        "chest": (ax_y, 0.12, np.pi),
        "head": (ax_y, 0.05, 0.3),
        "lwrist": (ax_z, 0.15, 1.0),
        "rwrist": (ax_z, 0.15, 1.0 + np.pi),
        "neck": (ax_x, 0.05, 0.2),
        "upperback": (ax_z, 0.05, 0.0),
        "lclavicle": (ax_z, 0.06, 0.0),
        "rclavicle": (ax_z, 0.06, np.pi),
        "lfingers": (ax_x, 0.1, 0.0),
        "rfingers": (ax_x, 0.1, np.pi),
        "root": (ax_z, 0.05, 0.0),
    }
    rot = quat.identity((n_frames, skel.n_joints))
    for j, (axis, a, ph) in swing.items():
        ang = a * amp * np.sin(phase + ph) + 0.01 * rng.standard_normal(n_frames)
        rot[:, skel.canonical[j]] = quat.from_axis_angle(np.broadcast_to(axis, (n_frames, 3)), ang)
    # the hips point along +x so the character faces +z; walk forward along z
    root = np.stack([np.zeros(n_frames), 0.95 + 0.02 * np.sin(2 * phase), 1.2 * t], axis=1)
    return Motion(skel, root, rot, fps, name=name, metadata={"subject": "synthetic"})
