"""Slow, obviously correct references for the relational-retrieval kernels (Müller et al. 2005).

NumPy / pure-Python twins of ``plugins/relational/_feature_kernels.py`` (geometric
primitives, the one-pass feature program), ``plugins/relational/segmentation.py``,
the inverted-list hits of ``plugins/relational/inverted.py`` and the kernels of
``plugins/relational/_match_kernels.py`` (m-mismatch scan, banded DTW).
"""

from __future__ import annotations

import numpy as np

from mocapflow.framework.joints import CANONICAL_JOINTS
from mocapflow.plugins.relational.features import THRESHOLDS


# --- geometry (float64, straight from the definitions) ---------------------------------
def plane_distance(p1, p2, p3, q, offset=0.0):
    n = np.cross(p2 - p1, p3 - p1)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    return np.sum((q - p1) * n, axis=-1) - offset


def normal_plane_distance(a, b, anchor, q, offset=0.0):
    n = (b - a) / np.linalg.norm(b - a, axis=-1, keepdims=True)
    return np.sum((q - anchor) * n, axis=-1) - offset


def point_segment_distance(q, a, b, samples=None):
    ab = b - a
    t = np.clip(np.sum((q - a) * ab, axis=-1) / np.sum(ab * ab, axis=-1), 0, 1)
    return np.linalg.norm(q - (a + t[..., None] * ab), axis=-1)


def segment_segment_distance(a0, a1, b0, b1, samples=2001):
    """Brute force: the minimum over a dense grid of one segment against the other."""
    s = np.linspace(0, 1, samples)
    out = []
    for i in range(len(a0)):
        pa = a0[i] + s[:, None] * (a1[i] - a0[i])
        out.append(point_segment_distance(pa, b0[i][None], b1[i][None]).min())
    return np.array(out)


def angle_between(a0, a1, b0, b1):
    u, v = a1 - a0, b1 - b0
    c = np.sum(u * v, axis=-1) / (np.linalg.norm(u, axis=-1) * np.linalg.norm(v, axis=-1))
    return np.degrees(np.arccos(np.clip(c, -1, 1)))


def speed(p, fps, offsets):
    """Per clip: central differences inside, one-sided at the ends, 0 for 1-frame clips."""
    out = np.zeros(len(p))
    for a, b in zip(offsets[:-1], offsets[1:], strict=True):
        for i in range(a, b):
            lo, hi = max(i - 1, a), min(i + 1, b - 1)
            out[i] = 0.0 if hi == lo else np.linalg.norm(p[hi] - p[lo]) * fps / (hi - lo)
    return out


# --- the 31 features ------------------------------------------------------------------
_FALLBACK = {
    "ltoes": "lankle",
    "rtoes": "rankle",
    "lfingers": "lwrist",
    "rfingers": "rwrist",
    "headtop": "head",
    "chest": "upperback",
    "neck": "head",
}


def feature_values(features, positions, fps, offsets):
    """Raw value per feature (angles in degrees, distances in metres), shape (T, F)."""
    pos = np.asarray(positions, dtype=np.float64)

    def joint(name):
        p = pos[:, CANONICAL_JOINTS.index(name)]
        while name in _FALLBACK and np.isnan(p).any():
            name = _FALLBACK[name]
            p = np.where(np.isnan(p), pos[:, CANONICAL_JOINTS.index(name)], p)
        return p

    floor = np.nanmin(pos[:, :, 1], axis=1)
    cols = []
    for d in features:
        vals = []
        for term in d.terms:
            j = [joint(n) for n in term]
            if d.op == "plane":
                v = plane_distance(*j)
            elif d.op == "nplane":
                v = normal_plane_distance(*j)
            elif d.op == "point_segment":
                v = point_segment_distance(*j)
            elif d.op == "segment_segment":
                v = segment_segment_distance(*j)
            elif d.op == "cos":
                v = angle_between(*j)
            elif d.op == "height":
                v = j[0][:, 1] - floor
            else:
                v = speed(j[0] - (j[1] if len(j) > 1 else 0.0), fps, offsets)
            vals.append(v)
        # angles: the larger one (min of cosines); distances: the smaller one
        cols.append(np.max(vals, axis=0) if d.op == "cos" else np.min(vals, axis=0))
    return np.stack(cols, axis=1)


def feature_bits(features, params, positions, fps, measures, offsets):
    values = feature_values(features, positions, fps, offsets)
    scale = {
        "hl": measures["humerus_length"],
        "hl/s": measures["humerus_length"],
        "sw": measures["shoulder_width"],
        "hw": measures["hip_width"],
        "deg": 1.0,
    }
    out = np.zeros(values.shape, bool)
    for i, d in enumerate(features):
        thr = params.thresholds.get(d.param, THRESHOLDS[d.param])
        s = scale[d.unit]
        out[:, i] = values[:, i] < thr * s if d.below else values[:, i] >= thr * s
    return out


# --- segmentation and hits ----------------------------------------------------------------
def segments(codes, offsets):
    """List of (start, end, code, clip) of maximal runs, split at clip boundaries."""
    out = []
    for c, (a, b) in enumerate(zip(offsets[:-1], offsets[1:], strict=True)):
        i = a
        while i < b:
            j = i
            while j < b and codes[j] == codes[i]:
                j += 1
            out.append((i, j, int(codes[i]), c))
            i = j
    return out


def exact_hits(w, clip, query):
    n = len(query)
    return [
        k for k in range(len(w) - n + 1) if all(w[k + i] == query[i] for i in range(n)) and clip[k] == clip[k + n - 1]
    ]


def fuzzy_hits(w, clip, sets):
    n = len(sets)
    return [
        k for k in range(len(w) - n + 1) if all(w[k + i] in sets[i] for i in range(n)) and clip[k] == clip[k + n - 1]
    ]


def adaptive_hits(w, clip, sets):
    """§5.2 literally: from each k with w_k in V_1 and w_{k-1} not in V_1 (or a clip start),
    extend maximal runs level by level. Returns a list of boundary tuples (k_1 .. k_{L+1})."""
    hits = []
    for k in range(len(w)):
        if w[k] not in sets[0] or (k > 0 and clip[k - 1] == clip[k] and w[k - 1] in sets[0]):
            continue
        bounds = [k]
        pos = k
        ok = True
        for v in sets:
            if pos >= len(w) or clip[pos] != clip[k] or w[pos] not in v:
                ok = False
                break
            while pos < len(w) and clip[pos] == clip[k] and w[pos] in v:
                pos += 1
            bounds.append(pos)
        if ok:
            hits.append(tuple(bounds))
    return hits


def mismatch_hits(w, clip, sets, m, allowed=None):
    n = len(sets)
    allowed = [True] * n if allowed is None else list(allowed)
    out = []
    for k in range(len(w) - n + 1):
        if clip[k] != clip[k + n - 1]:
            continue
        bad = [i for i in range(n) if w[k + i] not in sets[i]]
        if len(bad) <= m and all(allowed[i] for i in bad):
            out.append((k, len(bad)))
    return out


def dtw(a, b, lo=None, hi=None):
    """Full-matrix DTW with cells outside [lo, hi) forbidden; returns (cost, path)."""
    n, m = len(a), len(b)
    cost = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)
    if lo is not None:
        for i in range(n):
            cost[i, : max(lo[i], 0)] = np.inf
            cost[i, min(hi[i], m) :] = np.inf
    acc = np.full((n + 1, m + 1), np.inf)
    acc[0, 0] = 0.0
    for i in range(1, n + 1):
        for j in range(1, m + 1):
            acc[i, j] = cost[i - 1, j - 1] + min(acc[i - 1, j], acc[i, j - 1], acc[i - 1, j - 1])
    return acc[n, m]


# --- constructed poses (test fixtures) ----------------------------------------------------
#: A standing pose facing +z, left = +x, y up, metres (humerus 0.28, shoulders 0.4, hips 0.2).
STANDING = {
    "root": (0, 1.0, 0),
    "lhip": (0.1, 0.95, 0),
    "lknee": (0.1, 0.5, 0),
    "lankle": (0.1, 0.08, 0),
    "ltoes": (0.1, 0.0, 0.12),
    "rhip": (-0.1, 0.95, 0),
    "rknee": (-0.1, 0.5, 0),
    "rankle": (-0.1, 0.08, 0),
    "rtoes": (-0.1, 0.0, 0.12),
    "lowerback": (0, 1.1, 0),
    "upperback": (0, 1.25, 0),
    "chest": (0, 1.35, 0),
    "neck": (0, 1.5, 0),
    "head": (0, 1.6, 0),
    "headtop": (0, 1.75, 0),
    "lclavicle": (0.05, 1.45, 0),
    "lshoulder": (0.2, 1.45, 0),
    "lelbow": (0.25, 1.17, 0),
    "lwrist": (0.3, 0.92, 0),
    "lfingers": (0.32, 0.82, 0),
    "rclavicle": (-0.05, 1.45, 0),
    "rshoulder": (-0.2, 1.45, 0),
    "relbow": (-0.25, 1.17, 0),
    "rwrist": (-0.3, 0.92, 0),
    "rfingers": (-0.32, 0.82, 0),
}


def pose_array(**changes) -> np.ndarray:
    """Canonical positions (25, 3) of the standing pose with some joints moved."""
    p = dict(STANDING)
    p.update(changes)
    return np.array([p[j] for j in CANONICAL_JOINTS], dtype=np.float64)


def star_skeleton(rest: np.ndarray | None = None):
    """A skeleton whose joints are all children of the root, rest pose = ``rest`` (25, 3)."""
    from mocapflow.framework.skeleton import Skeleton

    rest = pose_array() if rest is None else rest
    offsets = rest - rest[0]
    offsets[0] = 0
    parents = np.r_[-1, np.zeros(len(CANONICAL_JOINTS) - 1, dtype=int)]
    return Skeleton(
        names=CANONICAL_JOINTS,
        parents=parents,
        offsets=offsets,
        canonical={j: i for i, j in enumerate(CANONICAL_JOINTS)},
        name="star",
    )


def motion_from_positions(frames: np.ndarray, fps: float = 30.0, name: str = "synthetic"):
    """A Motion whose canonical positions are exactly ``frames`` (T, 25, 3), metres."""
    from mocapflow.framework.motion import Motion

    frames = np.asarray(frames, dtype=np.float64)
    t = len(frames)
    sk = star_skeleton()
    rot = np.zeros((t, len(CANONICAL_JOINTS), 4))
    rot[..., 0] = 1.0
    local = frames - frames[:, :1]
    return Motion(sk, frames[:, 0], rot, fps, name=name, local_translations=local)
