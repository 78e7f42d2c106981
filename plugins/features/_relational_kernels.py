"""Numba kernels of the relational-feature primitives: one pass per frame, no temporaries.

No validation here: :mod:`.relational_primitives` validates, broadcasts to ``(N, 3)`` and
calls these. Each has a slow NumPy reference in ``tests/naive/relational.py``.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

_EPS = 1e-12


@njit(cache=True, inline="always")
def _psd(qx, qy, qz, ax, ay, az, bx, by, bz):  # pragma: no cover - compiled
    ux, uy, uz = bx - ax, by - ay, bz - az
    uu = ux * ux + uy * uy + uz * uz
    t = ((qx - ax) * ux + (qy - ay) * uy + (qz - az) * uz) / max(uu, _EPS)
    t = min(max(t, 0.0), 1.0)
    dx, dy, dz = qx - ax - t * ux, qy - ay - t * uy, qz - az - t * uz
    return math.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True)
def plane_distance(p1, p2, p3, q, offset, out):  # pragma: no cover - compiled
    for i in range(q.shape[0]):
        ux, uy, uz = p2[i, 0] - p1[i, 0], p2[i, 1] - p1[i, 1], p2[i, 2] - p1[i, 2]
        vx, vy, vz = p3[i, 0] - p1[i, 0], p3[i, 1] - p1[i, 1], p3[i, 2] - p1[i, 2]
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        norm = max(math.sqrt(nx * nx + ny * ny + nz * nz), _EPS)
        out[i] = ((q[i, 0] - p1[i, 0]) * nx + (q[i, 1] - p1[i, 1]) * ny + (q[i, 2] - p1[i, 2]) * nz) / norm - offset[i]


@njit(cache=True)
def normal_plane_distance(a, b, anchor, q, offset, out):  # pragma: no cover - compiled
    for i in range(q.shape[0]):
        nx, ny, nz = b[i, 0] - a[i, 0], b[i, 1] - a[i, 1], b[i, 2] - a[i, 2]
        norm = max(math.sqrt(nx * nx + ny * ny + nz * nz), _EPS)
        out[i] = ((q[i, 0] - anchor[i, 0]) * nx + (q[i, 1] - anchor[i, 1]) * ny
                  + (q[i, 2] - anchor[i, 2]) * nz) / norm - offset[i]


@njit(cache=True)
def point_segment_distance(q, a, b, out):  # pragma: no cover - compiled
    for i in range(q.shape[0]):
        out[i] = _psd(q[i, 0], q[i, 1], q[i, 2], a[i, 0], a[i, 1], a[i, 2], b[i, 0], b[i, 1], b[i, 2])


@njit(cache=True)
def segment_segment_distance(a0, a1, b0, b1, out):  # pragma: no cover - compiled
    for i in range(a0.shape[0]):
        ux, uy, uz = a1[i, 0] - a0[i, 0], a1[i, 1] - a0[i, 1], a1[i, 2] - a0[i, 2]
        vx, vy, vz = b1[i, 0] - b0[i, 0], b1[i, 1] - b0[i, 1], b1[i, 2] - b0[i, 2]
        wx, wy, wz = a0[i, 0] - b0[i, 0], a0[i, 1] - b0[i, 1], a0[i, 2] - b0[i, 2]
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
        # endpoint candidates make the clamped solution exact (minimum on the boundary)
        best = min(best, _psd(a0[i, 0], a0[i, 1], a0[i, 2], b0[i, 0], b0[i, 1], b0[i, 2], b1[i, 0], b1[i, 1], b1[i, 2]))
        best = min(best, _psd(a1[i, 0], a1[i, 1], a1[i, 2], b0[i, 0], b0[i, 1], b0[i, 2], b1[i, 0], b1[i, 1], b1[i, 2]))
        best = min(best, _psd(b0[i, 0], b0[i, 1], b0[i, 2], a0[i, 0], a0[i, 1], a0[i, 2], a1[i, 0], a1[i, 1], a1[i, 2]))
        best = min(best, _psd(b1[i, 0], b1[i, 1], b1[i, 2], a0[i, 0], a0[i, 1], a0[i, 2], a1[i, 0], a1[i, 1], a1[i, 2]))
        out[i] = best


@njit(cache=True)
def cos_between(a0, a1, b0, b1, out):  # pragma: no cover - compiled
    # the cosine, not the angle: thresholding cos against cos(theta) avoids an acos per frame
    for i in range(a0.shape[0]):
        ux, uy, uz = a1[i, 0] - a0[i, 0], a1[i, 1] - a0[i, 1], a1[i, 2] - a0[i, 2]
        vx, vy, vz = b1[i, 0] - b0[i, 0], b1[i, 1] - b0[i, 1], b1[i, 2] - b0[i, 2]
        nu = max(math.sqrt(ux * ux + uy * uy + uz * uz), _EPS)
        nv = max(math.sqrt(vx * vx + vy * vy + vz * vz), _EPS)
        out[i] = min(max((ux * vx + uy * vy + uz * vz) / (nu * nv), -1.0), 1.0)


@njit(cache=True)
def speed(x, starts, fps, out):  # pragma: no cover - compiled
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


@njit(cache=True)
def min_height(positions, out):  # pragma: no cover - compiled
    """Lowest y over the joints of each frame, ignoring NaN (NaN if all are)."""
    for i in range(positions.shape[0]):
        best = np.inf
        for j in range(positions.shape[1]):
            y = positions[i, j, 1]
            if y < best:
                best = y
        out[i] = best if best < np.inf else np.nan
