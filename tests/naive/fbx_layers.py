"""Slow, obviously correct FBX animation-layer blending: the twin of
``plugins/formats/_fbx_layers.py``.

One sample at a time, a line-by-line transcription of ufbx.c (``ufbxi_combine_anim_layer``,
``ufbx_euler_to_quat`` and ``ufbx_quat_to_euler`` with their six generated per-order cases,
``ufbx_quat_slerp``, ``ufbxi_mul_quat``, ``ufbxi_pow_abs``), quaternions as ufbx stores them
(x, y, z, w). Shares no code with the vectorised version (which writes the six orders as one
index-permuted formula).
"""

from __future__ import annotations

import math

D2R, R2D = math.pi / 180.0, 180.0 / math.pi
XYZ, XZY, YZX, YXZ, ZXY, ZYX, SPHERIC = range(7)


def euler_to_quat(v, order):
    vx, vy, vz = (a * (D2R * 0.5) for a in v)
    cx, sx = math.cos(vx), math.sin(vx)
    cy, sy = math.cos(vy), math.sin(vy)
    cz, sz = math.cos(vz), math.sin(vz)
    if order == XYZ:
        return (
            -cx * sy * sz + cy * cz * sx,
            cx * cz * sy + cy * sx * sz,
            cx * cy * sz - cz * sx * sy,
            cx * cy * cz + sx * sy * sz,
        )
    if order == XZY:
        return (
            cx * sy * sz + cy * cz * sx,
            cx * cz * sy + cy * sx * sz,
            cx * cy * sz - cz * sx * sy,
            cx * cy * cz - sx * sy * sz,
        )
    if order == YZX:
        return (
            -cx * sy * sz + cy * cz * sx,
            cx * cz * sy - cy * sx * sz,
            cx * cy * sz + cz * sx * sy,
            cx * cy * cz + sx * sy * sz,
        )
    if order == YXZ:
        return (
            -cx * sy * sz + cy * cz * sx,
            cx * cz * sy + cy * sx * sz,
            cx * cy * sz + cz * sx * sy,
            cx * cy * cz - sx * sy * sz,
        )
    if order == ZXY:
        return (
            cx * sy * sz + cy * cz * sx,
            cx * cz * sy - cy * sx * sz,
            cx * cy * sz - cz * sx * sy,
            cx * cy * cz + sx * sy * sz,
        )
    if order == ZYX:
        return (
            cx * sy * sz + cy * cz * sx,
            cx * cz * sy - cy * sx * sz,
            cx * cy * sz + cz * sx * sy,
            cx * cy * cz - sx * sy * sz,
        )
    return (0.0, 0.0, 0.0, 1.0)


def quat_to_euler(q, order):
    eps = 0.999999999
    qx, qy, qz, qw = q
    half = math.pi * 0.5
    if order == XYZ:
        t = 2.0 * (qw * qy - qx * qz)
        if abs(t) < eps:
            vy = math.asin(t)
            vz = math.atan2(2.0 * (qw * qz + qx * qy), 2.0 * (qw * qw + qx * qx) - 1.0)
            vx = -math.atan2(-2.0 * (qw * qx + qy * qz), 2.0 * (qw * qw + qz * qz) - 1.0)
        else:
            vy = math.copysign(half, t)
            vz = math.atan2(-2.0 * t * (qw * qx - qy * qz), t * (2.0 * qw * qy + 2.0 * qx * qz))
            vx = 0.0
    elif order == XZY:
        t = 2.0 * (qw * qz + qx * qy)
        if abs(t) < eps:
            vz = math.asin(t)
            vy = math.atan2(2.0 * (qw * qy - qx * qz), 2.0 * (qw * qw + qx * qx) - 1.0)
            vx = -math.atan2(-2.0 * (qw * qx - qy * qz), 2.0 * (qw * qw + qy * qy) - 1.0)
        else:
            vz = math.copysign(half, t)
            vy = math.atan2(2.0 * t * (qw * qx + qy * qz), -t * (2.0 * qx * qy - 2.0 * qw * qz))
            vx = 0.0
    elif order == YZX:
        t = 2.0 * (qw * qz - qx * qy)
        if abs(t) < eps:
            vz = math.asin(t)
            vx = math.atan2(2.0 * (qw * qx + qy * qz), 2.0 * (qw * qw + qy * qy) - 1.0)
            vy = -math.atan2(-2.0 * (qw * qy + qx * qz), 2.0 * (qw * qw + qx * qx) - 1.0)
        else:
            vz = math.copysign(half, t)
            vx = math.atan2(-2.0 * t * (qw * qy - qx * qz), t * (2.0 * qw * qz + 2.0 * qx * qy))
            vy = 0.0
    elif order == YXZ:
        t = 2.0 * (qw * qx + qy * qz)
        if abs(t) < eps:
            vx = math.asin(t)
            vz = math.atan2(2.0 * (qw * qz - qx * qy), 2.0 * (qw * qw + qy * qy) - 1.0)
            vy = -math.atan2(-2.0 * (qw * qy - qx * qz), 2.0 * (qw * qw + qz * qz) - 1.0)
        else:
            vx = math.copysign(half, t)
            vz = math.atan2(2.0 * t * (qw * qy + qx * qz), -t * (2.0 * qy * qz - 2.0 * qw * qx))
            vy = 0.0
    elif order == ZXY:
        t = 2.0 * (qw * qx - qy * qz)
        if abs(t) < eps:
            vx = math.asin(t)
            vy = math.atan2(2.0 * (qw * qy + qx * qz), 2.0 * (qw * qw + qz * qz) - 1.0)
            vz = -math.atan2(-2.0 * (qw * qz + qx * qy), 2.0 * (qw * qw + qy * qy) - 1.0)
        else:
            vx = math.copysign(half, t)
            vy = math.atan2(-2.0 * t * (qw * qz - qx * qy), t * (2.0 * qw * qx + 2.0 * qy * qz))
            vz = 0.0
    elif order == ZYX:
        t = 2.0 * (qw * qy + qx * qz)
        if abs(t) < eps:
            vy = math.asin(t)
            vx = math.atan2(2.0 * (qw * qx - qy * qz), 2.0 * (qw * qw + qz * qz) - 1.0)
            vz = -math.atan2(-2.0 * (qw * qz - qx * qy), 2.0 * (qw * qw + qx * qx) - 1.0)
        else:
            vy = math.copysign(half, t)
            vx = math.atan2(2.0 * t * (qw * qz + qx * qy), -t * (2.0 * qx * qz - 2.0 * qw * qy))
            vz = 0.0
    else:
        vx = vy = vz = 0.0
    return (vx * R2D, vy * R2D, vz * R2D)


def slerp(a, b, t):
    dot = sum(x * y for x, y in zip(a, b, strict=True))
    if dot < 0.0:
        dot = -dot
        b = tuple(-x for x in b)
    omega = math.acos(min(max(dot, 0.0), 1.0))
    if omega <= 1.175494351e-38:
        return a
    rcp_so = 1.0 / math.sin(omega)
    af = math.sin((1.0 - t) * omega) * rcp_so
    bf = math.sin(t * omega) * rcp_so
    r = [af * x + bf * y for x, y in zip(a, b, strict=True)]
    rcp_len = 1.0 / math.sqrt(sum(x * x for x in r))
    return tuple(x * rcp_len for x in r)


def mul_quat(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def pow_abs(v, e):
    if e <= 0.0:
        return 1.0
    if e >= 1.0:
        return v
    sign = -1.0 if v < 0.0 else 1.0
    return sign * (v * sign) ** e


def combine(mode, compose_rotation, compose_scale, weight, prop, result, value, order):
    """ufbxi_combine_anim_layer for one sample: ``mode`` the layer's BlendMode, ``prop``
    "t" / "r" / "s", ``result`` / ``value`` 3-tuples; returns the new result."""
    additive = mode == 0
    blended = mode in (0, 2)
    if additive:
        if compose_scale and prop == "s":
            return tuple(r * pow_abs(v, weight) for r, v in zip(result, value, strict=True))
        if compose_rotation and prop == "r":
            a = euler_to_quat(result, order)
            b = euler_to_quat(value, order)
            b = slerp((0.0, 0.0, 0.0, 1.0), b, weight)
            return quat_to_euler(mul_quat(a, b), order)
        return tuple(r + v * weight for r, v in zip(result, value, strict=True))
    if blended:
        rw = 1.0 - weight
        if compose_scale and prop == "s":
            return tuple(pow_abs(r, rw) * pow_abs(v, weight) for r, v in zip(result, value, strict=True))
        if compose_rotation and prop == "r":
            a = euler_to_quat(result, order)
            b = euler_to_quat(value, order)
            return quat_to_euler(slerp(a, b, weight), order)
        return tuple(r * rw + v * weight for r, v in zip(result, value, strict=True))
    return tuple(value)


def clamp_weight(percent):
    w = percent / 100.0
    if w < 0.0:
        w = 0.0
    if w > 0.9999899864196777:  # 0.99999f
        w = 1.0
    return w
