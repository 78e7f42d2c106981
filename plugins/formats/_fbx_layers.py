"""FBX animation layers: how the ``AnimationLayer`` objects of a take combine.

A take (``AnimationStack``) lists its layers in the order of its connections; each layer
holds curve nodes (``AnimationCurveNode``) that drive model properties. The rules are
ufbx's (``ufbxi_evaluate_props`` / ``ufbxi_combine_anim_layer`` of ufbx.c, which evaluates as
the FBX SDK does), per property and sample time:

* the property starts at its static value; the first layer of the take (index 0), when it
  drives the property, replaces it (whatever its weight and mode);
* each later layer that drives the property combines its value ``v`` into the result ``r``
  with the layer's weight ``w`` (``Weight`` in percent / 100, clamped to [0, 1], above 0.99999
  taken as 1; animated by a curve node on the layer's own ``Weight`` when the layer blends),
  by ``BlendMode`` (the SDK's ``EBlendMode``):

  - 0 additive: ``r + w v``; scaling with ``ScaleAccumulationMode`` 0 (multiply):
    ``r * |v|^w`` (sign kept); rotation with ``RotationAccumulationMode`` 0 (by layer):
    ``q(r) * slerp(1, q(v), w)`` as Euler angles again;
  - 2 override-passthrough: ``(1 - w) r + w v``; scaling (multiply): ``|r|^(1-w) |v|^w``;
    rotation (by layer): ``slerp(q(r), q(v), w)``;
  - 1 override, or any other value: ``v``.

  Quaternions ``q`` use the model's ``RotationOrder`` (6, spheric: the identity, as ufbx);
  accumulation mode 1 (by channel / additive scale) blends the three numbers as they are.
* ``Mute`` / ``Solo`` (the layer's state flags): a muted layer is skipped; when any layer
  is soloed, the layers that are not are skipped. The first layer (the base) is never
  skipped (MotionBuilder: the base layer cannot be muted). ufbx 0.0.5 ignores both flags,
  so a file that sets them reads differently there; no file of ufbx's corpus sets them.

Every function is vectorised over the sample times; the per-sample twin transcribing
ufbx's C is ``tests/naive/fbx_layers.py``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from mocapflow.framework import quaternions as quat

ADDITIVE, OVERRIDE, PASSTHROUGH = 0, 1, 2
#: ufbx's clamp: a weight above this float32 is 1.
_NEAR_ONE = float(np.float32(0.99999))
#: ufbx's gimbal threshold of quaternion -> Euler (double build).
_GIMBAL = 0.999999999
_ORDER_NAMES = ("xyz", "xzy", "yzx", "yxz", "zxy", "zyx")


@dataclass
class Layer:
    """One animation layer of a take: ``index`` in the take, ``weight`` (0-1, static),
    ``mode`` (``BlendMode``), ``compose_rotation`` / ``compose_scale`` (accumulation modes
    0), ``muted`` / ``solo`` (the flags), ``active`` (evaluated: not skipped by them),
    ``weight_curve`` an animated weight (percent) as ``(curve or None, default)`` (a curve
    node of this layer on its ``Weight``), ``has_weight`` whether the layer has a ``Weight``
    property (own or template; without one, an animated weight keyed from another layer
    reads 0, as in ufbx)."""

    name: str
    index: int
    weight: float
    mode: int
    compose_rotation: bool = True
    compose_scale: bool = True
    muted: bool = False
    solo: bool = False
    active: bool = True
    weight_curve: tuple[Any, ...] | None = None
    has_weight: bool = True

    @property
    def blended(self) -> bool:
        return self.mode in (ADDITIVE, PASSTHROUGH)


def clamp_weight(percent: np.ndarray | float) -> np.ndarray:
    """Layer weight from ``Weight`` in percent, clamped as ufbx does."""
    w = np.asarray(percent, dtype=np.float64) / 100.0
    w = np.where(w < 0.0, 0.0, w)
    return np.where(w > _NEAR_ONE, 1.0, w)


def euler_quat(angles: np.ndarray, order: str) -> np.ndarray:
    """Quaternion (w, x, y, z) of Euler angles (degrees, ``angles[..., a]`` about axis
    ``a`` = x, y, z) applied in ``order`` (``xyz``: x first, matrix ``Rz Ry Rx``): the product
    ``q_k q_j q_i`` of the three axis rotations written out."""
    i, j, k = ("xyz".index(a) for a in order[::-1])  # q = q_i q_j q_k, i applied last
    h = np.deg2rad(np.asarray(angles, dtype=float)) * 0.5
    c, s = np.cos(h), np.sin(h)
    c1, c2, c3, s1, s2, s3 = c[..., i], c[..., j], c[..., k], s[..., i], s[..., j], s[..., k]
    e = 1.0 if (j - i) % 3 == 1 else -1.0  # e_i e_j = e * e_k
    out = np.empty(h.shape[:-1] + (4,))
    out[..., 0] = c1 * c2 * c3 - e * s1 * s2 * s3
    out[..., 1 + i] = s1 * c2 * c3 + e * c1 * s2 * s3
    out[..., 1 + j] = c1 * s2 * c3 - e * s1 * c2 * s3
    out[..., 1 + k] = c1 * c2 * s3 + e * s1 * s2 * c3
    return out


def quat_euler(q: np.ndarray, order: str) -> np.ndarray:
    """Euler angles (degrees, about x, y, z) of quaternions (w, x, y, z) in ``order`` (first
    applied first): ufbx's ``ufbx_quat_to_euler`` written once for the six orders (middle
    angle in [-90, 90]; within 1e-9 of the gimbal lock the first angle is 0)."""
    i, j, k = ("xyz".index(a) for a in order)  # i applied first
    e = 1.0 if (j - i) % 3 == 1 else -1.0
    w, qi, qj, qk = q[..., 0], q[..., 1 + i], q[..., 1 + j], q[..., 1 + k]
    t = 2.0 * (w * qj - e * qi * qk)
    lock = np.abs(t) >= _GIMBAL
    out = np.empty(q.shape[:-1] + (3,))
    out[..., j] = np.where(lock, np.copysign(np.pi * 0.5, t), np.arcsin(np.clip(t, -1.0, 1.0)))
    out[..., k] = np.where(
        lock,
        np.arctan2(-e * 2.0 * t * (w * qi - e * qj * qk), t * (2.0 * w * qj + 2.0 * e * qi * qk)),
        np.arctan2(2.0 * (w * qk + e * qi * qj), 2.0 * (w * w + qi * qi) - 1.0),
    )
    out[..., i] = np.where(lock, 0.0, np.arctan2(2.0 * (w * qi + e * qj * qk), 2.0 * (w * w + qk * qk) - 1.0))
    return np.rad2deg(out)


def slerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """ufbx's ``ufbx_quat_slerp`` of quaternion arrays (..., 4) by ``t`` (...): along the
    shorter arc, ``a`` where the two coincide, normalised."""
    dot = (a * b).sum(axis=-1)
    b = np.where((dot < 0.0)[..., None], -b, b)
    omega = np.arccos(np.clip(np.abs(dot), 0.0, 1.0))
    same = omega <= 1.175494351e-38
    with np.errstate(divide="ignore", invalid="ignore"):
        rcp = 1.0 / np.sin(omega)
        af = np.sin((1.0 - t) * omega) * rcp
        bf = np.sin(t * omega) * rcp
        r = af[..., None] * a + bf[..., None] * b
        r = r / np.sqrt((r * r).sum(axis=-1))[..., None]
    return np.where(same[..., None], a, r)


def _pow_abs(v: np.ndarray, e: np.ndarray) -> np.ndarray:
    """``sign(v) |v|^e``; 1 for ``e <= 0``, ``v`` for ``e >= 1`` (ufbx's ``ufbxi_pow_abs``)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        p = np.where(v < 0.0, -1.0, 1.0) * np.abs(v) ** e
    return np.where(e <= 0.0, 1.0, np.where(e >= 1.0, v, p))


def _to_quat(euler: np.ndarray, order: int) -> np.ndarray:
    if not 0 <= order < 6:  # spheric (6) or unknown: ufbx's identity
        q = np.zeros(euler.shape[:-1] + (4,))
        q[..., 0] = 1.0
        return q
    return euler_quat(euler, _ORDER_NAMES[order])


def _to_euler(q: np.ndarray, order: int) -> np.ndarray:
    if not 0 <= order < 6:
        return np.zeros(q.shape[:-1] + (3,))
    return quat_euler(q, _ORDER_NAMES[order])


def combine(
    result: np.ndarray, value: np.ndarray, weight: np.ndarray, layer: Layer, channel: str, order: int
) -> np.ndarray:
    """Combine a later layer's ``value`` (F, 3) into ``result`` (F, 3) with ``weight`` (F,)
    for channel ``"t"``, ``"r"`` (Euler degrees, the model's ``RotationOrder`` ``order``) or
    ``"s"`` (module doc)."""
    w = np.broadcast_to(np.asarray(weight, dtype=np.float64), result.shape[:1])
    if not layer.blended:
        return cast("np.ndarray", value.copy())
    if channel == "s" and layer.compose_scale:
        if layer.mode == ADDITIVE:
            return cast("np.ndarray", result * _pow_abs(value, w[:, None]))
        return cast("np.ndarray", _pow_abs(result, 1.0 - w[:, None]) * _pow_abs(value, w[:, None]))
    if channel == "r" and layer.compose_rotation:
        a, b = _to_quat(result, order), _to_quat(value, order)
        if layer.mode == ADDITIVE:
            one = np.zeros_like(b)
            one[:, 0] = 1.0
            q = quat.mul(a, slerp(one, b, w))
        else:
            q = slerp(a, b, w)
        return _to_euler(q, order)
    if layer.mode == ADDITIVE:
        return result + value * w[:, None]
    return result * (1.0 - w[:, None]) + value * w[:, None]
