"""Vectorised unit-quaternion algebra.

Quaternions are stored as ``(..., 4)`` float arrays in **(w, x, y, z)** order (scalar
first). All functions broadcast over leading axes and never loop over frames in Python.
Rotations act on column vectors: ``rotate(q, v) = q v q*``; composition ``mul(a, b)``
applies ``b`` first, then ``a`` (same as matrix products ``A @ B``).
"""

from __future__ import annotations

import numpy as np

_AXES = {"x": 0, "y": 1, "z": 2}


def identity(shape: tuple[int, ...] = ()) -> np.ndarray:
    """Identity quaternions of the given leading shape, shape ``shape + (4,)``."""
    q = np.zeros(shape + (4,))
    q[..., 0] = 1.0
    return q


def mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` (rotation ``b`` then ``a``), broadcasting."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b), -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def conjugate(q: np.ndarray) -> np.ndarray:
    """Conjugate (= inverse for unit quaternions)."""
    out = np.array(q, dtype=float, copy=True)
    out[..., 1:] *= -1.0
    return out


def normalize(q: np.ndarray) -> np.ndarray:
    """Scale to unit norm; zero quaternions become the identity."""
    q = np.asarray(q, dtype=float)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    out = np.where(n > 0, q / np.where(n > 0, n, 1.0), identity(q.shape[:-1]))
    return out


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v (..., 3)`` by unit quaternions ``q (..., 4)``."""
    q = np.asarray(q)
    v = np.asarray(v)
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def from_axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Quaternion for a rotation of ``angle`` radians about unit ``axis (..., 3)``."""
    axis = np.asarray(axis, dtype=float)
    half = 0.5 * np.asarray(angle, dtype=float)[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * axis], axis=-1)


def from_euler(angles: np.ndarray, order: str, degrees: bool = True) -> np.ndarray:
    """``R[order[0]] @ R[order[1]] @ ...`` of ``angles (..., len(order))``: intrinsic
    rotations in listed channel order (BVH convention; the last axis acts first)."""
    angles = np.asarray(angles, dtype=float)
    if degrees:
        angles = np.deg2rad(angles)
    q = identity(angles.shape[:-1])
    for i, letter in enumerate(order.lower()):
        axis = np.zeros(3)
        axis[_AXES[letter]] = 1.0
        q = mul(q, from_axis_angle(axis, angles[..., i]))
    return q


def to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions."""
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def from_matrix(m: np.ndarray) -> np.ndarray:
    """Unit quaternions (w >= 0) of rotation matrices ``(..., 3, 3)`` (Shepperd's method)."""
    m = np.asarray(m, dtype=float)
    tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    cand = np.stack(
        [
            np.stack(
                [1 + tr, m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1
            ),
            np.stack(
                [
                    m[..., 2, 1] - m[..., 1, 2],
                    1 + 2 * m[..., 0, 0] - tr,
                    m[..., 0, 1] + m[..., 1, 0],
                    m[..., 0, 2] + m[..., 2, 0],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 0, 1] + m[..., 1, 0],
                    1 + 2 * m[..., 1, 1] - tr,
                    m[..., 1, 2] + m[..., 2, 1],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 1, 0] - m[..., 0, 1],
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 1, 2] + m[..., 2, 1],
                    1 + 2 * m[..., 2, 2] - tr,
                ],
                -1,
            ),
        ],
        axis=-2,
    )
    # pick the numerically largest candidate row per matrix
    diag = np.stack([tr, m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]], -1)
    best = np.argmax(diag, axis=-1)
    q = np.take_along_axis(cand, best[..., None, None], axis=-2)[..., 0, :]
    q = normalize(q)
    return np.where(q[..., :1] < 0, -q, q)


def to_euler(q: np.ndarray, order: str, degrees: bool = True) -> np.ndarray:
    """Angles ``(..., 3)`` with ``from_euler(angles, order) == ±q`` (three distinct axes)."""
    order = order.lower()
    if len(order) != 3 or len(set(order)) != 3:
        raise ValueError(f"to_euler needs three distinct axes, got {order!r}")
    i, j, k = (_AXES[c] for c in order)
    r = to_matrix(q)
    # sign of the permutation (i, j, k) decides the signs in the decomposition
    sign = 1.0 if (j - i) % 3 == 1 else -1.0
    sj = np.clip(sign * r[..., i, k], -1.0, 1.0)
    b = np.arcsin(sj)
    a = np.arctan2(-sign * r[..., j, k], r[..., k, k])
    c = np.arctan2(-sign * r[..., i, j], r[..., i, i])
    # gimbal lock: put the whole twist into the first angle
    lock = np.abs(sj) > 1.0 - 1e-12
    if np.any(lock):
        a = np.where(lock, np.arctan2(sign * r[..., k, j], r[..., j, j]), a)
        c = np.where(lock, 0.0, c)
    out = np.stack([a, b, c], axis=-1)
    return np.rad2deg(out) if degrees else out


def geodesic_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angle in radians, in [0, pi], between unit quaternions (sign-invariant)."""
    d = np.abs(np.sum(np.asarray(a) * np.asarray(b), axis=-1))
    return np.asarray(2.0 * np.arccos(np.clip(d, 0.0, 1.0)))


def slerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation along the shorter arc, ``t`` broadcasting to ``(...)``."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    t = np.asarray(t, dtype=float)[..., None]
    dot = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(dot < 0, -b, b)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, 0.0, 1.0))
    sin_t = np.sin(theta)
    small = sin_t < 1e-8
    safe = np.where(small, 1.0, sin_t)
    wa = np.where(small, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    wb = np.where(small, t, np.sin(t * theta) / safe)
    return normalize(wa * a + wb * b)


def make_continuous(q: np.ndarray, axis: int = 0) -> np.ndarray:
    """Flip signs along ``axis`` (time) so consecutive quaternions lie in one hemisphere."""
    q = np.array(q, dtype=float, copy=True)
    q = np.moveaxis(q, axis, 0)
    if q.shape[0] > 1:
        dots = np.sum(q[1:] * q[:-1], axis=-1)
        flips = np.cumprod(np.where(dots < 0, -1.0, 1.0), axis=0)
        q[1:] *= flips[..., None]
    return np.moveaxis(q, 0, axis)


def mean_of_outer(outer: np.ndarray) -> np.ndarray:
    """Chordal L2 mean (..., 4), ``w >= 0``, from ``sum q q^T`` (..., 4, 4): the principal
    eigenvector (Markley et al. 2007; sign-invariant)."""
    _, vecs = np.linalg.eigh(outer)
    q = vecs[..., :, -1]
    return np.where(q[..., :1] < 0, -q, q)


def chordal_mean(q: np.ndarray) -> np.ndarray:
    """Chordal L2 mean of unit quaternions ``(n, 4)`` -> ``(4,)``."""
    q = np.asarray(q, dtype=float)
    return mean_of_outer(q.T @ q)


def euler_extrinsic(angles: np.ndarray, order: str, degrees: bool) -> np.ndarray:
    """Rotations about fixed axes in listed order (ASF/AMC: ``"xyz"`` is ``Rz Ry Rx``)."""
    angles = np.asarray(angles, dtype=float)
    return from_euler(angles[..., ::-1], order[::-1], degrees=degrees)


def euler_extrinsic_inverse(q: np.ndarray, order: str, degrees: bool) -> np.ndarray:
    """Angles ``(..., len(order))`` with ``euler_extrinsic(angles, order) == ±q``, for one to
    three axes; missing axes (zero) go in the middle, away from gimbal lock."""
    order = order.lower()
    if not order:
        return np.zeros(np.shape(q)[:-1] + (0,))
    missing = [a for a in "xyz" if a not in order]
    full = order[0] + "".join(missing) + order[1:]
    ang = to_euler(q, full[::-1], degrees=degrees)[..., ::-1]
    pick = [full.index(a) for a in order]
    return ang[..., pick]
