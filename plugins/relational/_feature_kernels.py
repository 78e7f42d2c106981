"""Numba kernels of the relational-feature primitives: one pass per frame, no temporaries.

No validation here: :mod:`.relational_primitives` validates, broadcasts to ``(N, 3)`` and
calls these. Each has a slow NumPy reference in ``tests/naive/relational.py``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_EPS = 1e-12
# fast-math without the no-NaN/no-inf assumptions: missing joints are NaN and must stay so
_FAST = {"nsz", "arcp", "contract", "afn", "reassoc"}


@njit(cache=True, inline="always", error_model="numpy", fastmath=_FAST)
def _psd(
    qx: float, qy: float, qz: float, ax: float, ay: float, az: float, bx: float, by: float, bz: float
) -> float:  # pragma: no cover - compiled
    ux, uy, uz = bx - ax, by - ay, bz - az
    uu = ux * ux + uy * uy + uz * uz
    t = ((qx - ax) * ux + (qy - ay) * uy + (qz - az) * uz) / max(uu, _EPS)
    t = min(max(t, 0.0), 1.0)
    dx, dy, dz = qx - ax - t * ux, qy - ay - t * uy, qz - az - t * uz
    return math.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True, error_model="numpy", fastmath=_FAST)
def plane_distance(
    p1: np.ndarray, p2: np.ndarray, p3: np.ndarray, q: np.ndarray, offset: np.ndarray, out: np.ndarray
) -> None:  # pragma: no cover - compiled
    for i in range(q.shape[0]):
        ux, uy, uz = p2[i, 0] - p1[i, 0], p2[i, 1] - p1[i, 1], p2[i, 2] - p1[i, 2]
        vx, vy, vz = p3[i, 0] - p1[i, 0], p3[i, 1] - p1[i, 1], p3[i, 2] - p1[i, 2]
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        norm = max(math.sqrt(nx * nx + ny * ny + nz * nz), _EPS)
        out[i] = ((q[i, 0] - p1[i, 0]) * nx + (q[i, 1] - p1[i, 1]) * ny + (q[i, 2] - p1[i, 2]) * nz) / norm - offset[i]


@njit(cache=True, error_model="numpy", fastmath=_FAST)
def normal_plane_distance(
    a: np.ndarray, b: np.ndarray, anchor: np.ndarray, q: np.ndarray, offset: np.ndarray, out: np.ndarray
) -> None:  # pragma: no cover - compiled
    for i in range(q.shape[0]):
        nx, ny, nz = b[i, 0] - a[i, 0], b[i, 1] - a[i, 1], b[i, 2] - a[i, 2]
        norm = max(math.sqrt(nx * nx + ny * ny + nz * nz), _EPS)
        out[i] = (
            (q[i, 0] - anchor[i, 0]) * nx + (q[i, 1] - anchor[i, 1]) * ny + (q[i, 2] - anchor[i, 2]) * nz
        ) / norm - offset[i]


@njit(cache=True, error_model="numpy", fastmath=_FAST)
def point_segment_distance(
    q: np.ndarray, a: np.ndarray, b: np.ndarray, out: np.ndarray
) -> None:  # pragma: no cover - compiled
    for i in range(q.shape[0]):
        out[i] = _psd(q[i, 0], q[i, 1], q[i, 2], a[i, 0], a[i, 1], a[i, 2], b[i, 0], b[i, 1], b[i, 2])


@njit(cache=True, error_model="numpy", fastmath=_FAST)
def segment_segment_distance(
    a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray, out: np.ndarray
) -> None:  # pragma: no cover - compiled
    for i in range(a0.shape[0]):
        out[i] = _segseg(
            a0[i, 0],
            a0[i, 1],
            a0[i, 2],
            a1[i, 0],
            a1[i, 1],
            a1[i, 2],
            b0[i, 0],
            b0[i, 1],
            b0[i, 2],
            b1[i, 0],
            b1[i, 1],
            b1[i, 2],
        )


@njit(cache=True, error_model="numpy", fastmath=_FAST)
def cos_between(
    a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray, out: np.ndarray
) -> None:  # pragma: no cover - compiled
    # the cosine, not the angle: thresholding cos against cos(theta) avoids an acos per frame
    for i in range(a0.shape[0]):
        ux, uy, uz = a1[i, 0] - a0[i, 0], a1[i, 1] - a0[i, 1], a1[i, 2] - a0[i, 2]
        vx, vy, vz = b1[i, 0] - b0[i, 0], b1[i, 1] - b0[i, 1], b1[i, 2] - b0[i, 2]
        nu = max(math.sqrt(ux * ux + uy * uy + uz * uz), _EPS)
        nv = max(math.sqrt(vx * vx + vy * vy + vz * vz), _EPS)
        out[i] = min(max((ux * vx + uy * vy + uz * vz) / (nu * nv), -1.0), 1.0)


@njit(cache=True, error_model="numpy", fastmath=_FAST)
def speed(x: np.ndarray, starts: np.ndarray, fps: float, out: np.ndarray) -> None:  # pragma: no cover - compiled
    n = x.shape[0]
    for i in range(n):
        first = starts[i]
        last = i == n - 1 or starts[i + 1]
        lo = i if first else i - 1
        hi = i if last else i + 1
        steps = hi - lo
        if steps == 0:
            out[i] = 0.0
            continue
        dx, dy, dz = x[hi, 0] - x[lo, 0], x[hi, 1] - x[lo, 1], x[hi, 2] - x[lo, 2]
        out[i] = math.sqrt(dx * dx + dy * dy + dz * dz) * fps / steps


@njit(cache=True, error_model="numpy", fastmath=_FAST)
def min_height(positions: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Lowest y over the joints of each frame, ignoring NaN (NaN if all are)."""
    for i in range(positions.shape[0]):
        best = np.inf
        for j in range(positions.shape[1]):
            y = positions[i, j, 1]
            if y < best:
                best = y
        out[i] = best if best < np.inf else np.nan


# --- all features in one pass ------------------------------------------------------------
# op codes of the feature program (see relational.py, which compiles the feature table)
OP_PLANE, OP_NPLANE, OP_PSEG, OP_SEGSEG, OP_COS, OP_HEIGHT, OP_SPEED = 0, 1, 2, 3, 4, 5, 6


@njit(cache=True, inline="always", error_model="numpy", fastmath=_FAST)
def _joint(
    pos: np.ndarray, i: int, j: int, fallback: np.ndarray
) -> tuple[float, float, float]:  # pragma: no cover - compiled
    # substitute a missing joint (NaN) by its fallback (toes -> ankle...), per frame
    while j >= 0 and math.isnan(pos[i, j, 0]) and fallback[j] >= 0:
        j = fallback[j]
    return pos[i, j, 0], pos[i, j, 1], pos[i, j, 2]


@njit(cache=True, inline="always", error_model="numpy", fastmath=_FAST)
def _value(
    pos: np.ndarray,
    i: int,
    lo: int,
    hi: int,
    miny: float,
    fps: float,
    op: int,
    joints: np.ndarray,
    f: int,
    n_terms: int,
    fallback: np.ndarray,
) -> float:  # pragma: no cover - compiled
    """Value of feature ``f`` at frame ``i``: min over its terms of the op."""
    best = np.inf
    # index the full arrays (no slices: a slice per call costs a reference count)
    for t in range(n_terms):
        j0, j1, j2, j3 = joints[f, t, 0], joints[f, t, 1], joints[f, t, 2], joints[f, t, 3]
        if op == OP_SPEED:
            if hi == lo:
                v = 0.0
            else:
                ax, ay, az = _joint(pos, hi, j0, fallback)
                bx, by, bz = _joint(pos, lo, j0, fallback)
                if j1 >= 0:  # relative to a reference joint
                    cx, cy, cz = _joint(pos, hi, j1, fallback)
                    dx, dy, dz = _joint(pos, lo, j1, fallback)
                    ax, ay, az = ax - cx, ay - cy, az - cz
                    bx, by, bz = bx - dx, by - dy, bz - dz
                ex, ey, ez = ax - bx, ay - by, az - bz
                v = math.sqrt(ex * ex + ey * ey + ez * ez) * fps / (hi - lo)
        elif op == OP_HEIGHT:
            ax, ay, az = _joint(pos, i, j0, fallback)
            v = ay - miny
        else:
            ax, ay, az = _joint(pos, i, j0, fallback)
            bx, by, bz = _joint(pos, i, j1, fallback)
            cx, cy, cz = _joint(pos, i, j2, fallback)
            if op == OP_PSEG:
                v = _psd(ax, ay, az, bx, by, bz, cx, cy, cz)
            else:
                dx, dy, dz = _joint(pos, i, j3, fallback)
                if op == OP_PLANE:
                    ux, uy, uz = bx - ax, by - ay, bz - az
                    wx, wy, wz = cx - ax, cy - ay, cz - az
                    nx, ny, nz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
                    norm = max(math.sqrt(nx * nx + ny * ny + nz * nz), _EPS)
                    v = ((dx - ax) * nx + (dy - ay) * ny + (dz - az) * nz) / norm
                elif op == OP_NPLANE:
                    nx, ny, nz = bx - ax, by - ay, bz - az
                    norm = max(math.sqrt(nx * nx + ny * ny + nz * nz), _EPS)
                    v = ((dx - cx) * nx + (dy - cy) * ny + (dz - cz) * nz) / norm
                elif op == OP_COS:
                    ux, uy, uz = bx - ax, by - ay, bz - az
                    wx, wy, wz = dx - cx, dy - cy, dz - cz
                    nu = max(math.sqrt(ux * ux + uy * uy + uz * uz), _EPS)
                    nw = max(math.sqrt(wx * wx + wy * wy + wz * wz), _EPS)
                    v = min(max((ux * wx + uy * wy + uz * wz) / (nu * nw), -1.0), 1.0)
                else:  # OP_SEGSEG
                    v = _segseg(ax, ay, az, bx, by, bz, cx, cy, cz, dx, dy, dz)
        if v < best or math.isnan(v):
            best = v
    return best


@njit(cache=True, inline="always", error_model="numpy", fastmath=_FAST)
def _frame(pos: np.ndarray, starts: np.ndarray, i: int) -> tuple[int, int, float]:  # pragma: no cover - compiled
    # prange indices are unsigned: keep the arithmetic in int64
    i = np.int64(i)
    n = np.int64(pos.shape[0])
    miny = np.inf
    for j in range(pos.shape[1]):
        y = pos[i, j, 1]
        if y < miny:
            miny = y
    lo = i if starts[i] else i - 1
    hi = i if (i == n - 1 or starts[i + 1]) else i + 1
    return lo, hi, miny


@njit(cache=True, error_model="numpy", fastmath=_FAST)
def feature_values(
    pos: np.ndarray,
    starts: np.ndarray,
    fps: float,
    ops: np.ndarray,
    joints: np.ndarray,
    n_terms: np.ndarray,
    fallback: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Raw values ``out (T, F)`` of every feature (distances m, speeds m/s, angles as cosines).

    ``pos`` (T, J, 3); ``starts`` (T,) first frame of each clip; ``ops`` (F,) op codes;
    ``joints`` (F, 4, 4) joint indices per term (-1 unused); ``n_terms`` (F,);
    ``fallback`` (J,) joint used where a joint is NaN (-1 none).
    """
    for i in range(pos.shape[0]):
        lo, hi, miny = _frame(pos, starts, i)
        for f in range(ops.shape[0]):
            out[i, f] = _value(pos, i, lo, hi, miny, fps, ops[f], joints, f, n_terms[f], fallback)


@njit(cache=True, error_model="numpy", fastmath=_FAST)
def feature_bits(
    pos: np.ndarray,
    starts: np.ndarray,
    fps: float,
    ops: np.ndarray,
    joints: np.ndarray,
    n_terms: np.ndarray,
    fallback: np.ndarray,
    unit: np.ndarray,
    scale: np.ndarray,
    thr: np.ndarray,
    below: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Thresholded features in the same pass: ``out[i, f] = value (>= | <) thr[f] * scale[i, unit[f]]``;
    NaN gives False."""
    for i in range(pos.shape[0]):
        lo, hi, miny = _frame(pos, starts, i)
        for f in range(ops.shape[0]):
            v = _value(pos, i, lo, hi, miny, fps, ops[f], joints, f, n_terms[f], fallback)
            sc = scale[i, unit[f]]
            if below[f]:
                out[i, f] = v < thr[f] * sc
            else:
                out[i, f] = v >= thr[f] * sc


@njit(cache=True, inline="always", error_model="numpy", fastmath=_FAST)
def _segseg(
    a0x: float,
    a0y: float,
    a0z: float,
    a1x: float,
    a1y: float,
    a1z: float,
    b0x: float,
    b0y: float,
    b0z: float,
    b1x: float,
    b1y: float,
    b1z: float,
) -> float:  # pragma: no cover - compiled
    ux, uy, uz = a1x - a0x, a1y - a0y, a1z - a0z
    vx, vy, vz = b1x - b0x, b1y - b0y, b1z - b0z
    wx, wy, wz = a0x - b0x, a0y - b0y, a0z - b0z
    a = ux * ux + uy * uy + uz * uz
    b = ux * vx + uy * vy + uz * vz
    c = vx * vx + vy * vy + vz * vz
    d = ux * wx + uy * wy + uz * wz
    e = vx * wx + vy * wy + vz * wz
    den = a * c - b * b
    s = min(max((b * e - c * d) / den, 0.0), 1.0) if den > _EPS else 0.0
    t = min(max((b * s + e) / c, 0.0), 1.0) if c > _EPS else 0.0
    s = min(max((b * t - d) / a, 0.0), 1.0) if a > _EPS else 0.0
    dx, dy, dz = wx + s * ux - t * vx, wy + s * uy - t * vy, wz + s * uz - t * vz
    best = math.sqrt(dx * dx + dy * dy + dz * dz)
    best = min(best, _psd(a0x, a0y, a0z, b0x, b0y, b0z, b1x, b1y, b1z))
    best = min(best, _psd(a1x, a1y, a1z, b0x, b0y, b0z, b1x, b1y, b1z))
    best = min(best, _psd(b0x, b0y, b0z, a0x, a0y, a0z, a1x, a1y, a1z))
    best = min(best, _psd(b1x, b1y, b1z, a0x, a0y, a0z, a1x, a1y, a1z))
    return best
