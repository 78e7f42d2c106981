"""FBX animation curves: key layout, tangents, interpolation and extrapolation.

An ``AnimationCurve`` holds ``KeyTime`` (KTime ticks), ``KeyValueFloat`` and run-length
encoded key attributes: ``KeyAttrFlags`` (one int per run), ``KeyAttrDataFloat`` (four
float32 per run) and ``KeyAttrRefCount`` (keys per run). Per key, the flags give the
interpolation of the segment that starts there (``0x2`` constant, ``0x4`` linear, ``0x8``
cubic; constant with ``0x100`` takes the next key's value) and for cubic keys the tangent
mode (``0x400`` user, ``0x800`` broken, ``0x200`` TCB, else auto; ``0x1000`` clamp,
``0x2000`` time independent, ``0x4000`` progressive clamp). The data floats are the right
slope, the next key's left slope (value per second), the packed weights (the float's bits:
two 16-bit fixed point numbers in units of 10^-4, right weight in the low half, next-left
in the high half, used when flags ``0x1000000`` / ``0x2000000`` are set; default 1/3) and
velocities (unused, as in the FBX SDK's evaluation). A cubic segment is a Bezier curve in
(time, value) whose control points sit ``weight * segment length`` after / before its keys
along the tangents; the time parameter is found by Newton iteration.

``Pre-Extrapolation`` / ``Post-Extrapolation`` (``Type``: ``C`` constant, ``K`` slope,
``R`` repeat, ``A`` repeat relative, ``M`` mirror; ``Repetition`` count, < 0: forever)
define the value outside the keys.

The rules follow ufbx (which matches the FBX SDK's evaluation; ``benchmarks/fbx_parity.py``
compares): tangents are solved once per curve (:func:`prepare`, vectorised over the keys),
evaluation (:func:`evaluate`) is vectorised over the sample times. The per-key reference
twin is ``tests/naive/fbx_curves.py``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import cast

import numpy as np

from mocapflow.framework.errors import ParseError

from ._fbx_parse import Node

CONSTANT, LINEAR, CUBIC = 0x2, 0x4, 0x8
CONSTANT_NEXT = 0x100
TANGENT_TCB, TANGENT_USER = 0x200, 0x400
CLAMP, TIME_INDEPENDENT, CLAMP_PROGRESSIVE = 0x1000, 0x2000, 0x4000
WEIGHTED_RIGHT, WEIGHTED_NEXT_LEFT = 0x1000000, 0x2000000
#: Segment kinds after :func:`prepare`.
K_PREV, K_NEXT, K_LINEAR, K_CUBIC = 0, 1, 2, 3
EXTRAPOLATION = {ord("C"): "constant", ord("K"): "slope", ord("R"): "repeat", ord("A"): "relative", ord("M"): "mirror"}
_THIRD = np.float32(0.333333)
#: Seconds within which a sample time is a key's time (a KTime tick is 2.2e-11 s).
SNAP = 1e-9


@dataclass
class Curve:
    """One animation curve with its tangents solved.

    ``ticks`` (K,) int64 key times, ``times`` (K,) seconds, ``values`` (K,), ``kind`` (K,)
    segment kind starting at each key, ``left_dx/left_dy/right_dx/right_dy`` (K,) tangent
    handles (seconds, value units; float32 as the SDK stores them), ``pre``/``post``:
    (mode, repetitions) extrapolation, ``ktps`` ticks per second."""

    ticks: np.ndarray
    times: np.ndarray
    values: np.ndarray
    kind: np.ndarray
    left_dx: np.ndarray
    left_dy: np.ndarray
    right_dx: np.ndarray
    right_dy: np.ndarray
    pre: tuple[str, int]
    post: tuple[str, int]
    ktps: int


def _array(node: Node, name: str) -> np.ndarray | None:
    child = node.find(name)
    if child is None or not child.props or not isinstance(child.props[0], np.ndarray):
        return None
    return child.props[0]


def _char(data: bytes, version: int, node: Node) -> int | None:
    """The first property of ``node`` as the raw byte of a ``C`` (char) property: the
    container reads ``C`` as a bool, but ``Type`` of an extrapolation is a letter."""
    head = 25 if version >= 7500 else 13
    p = node.offset + head - 1
    if p >= len(data):
        return None
    p += 1 + data[p]  # past the name
    if p + 1 < len(data) and data[p : p + 1] == b"C":
        return data[p + 1]
    return None


def _extrapolation(node: Node, name: str, data: bytes, version: int) -> tuple[str, int]:
    child = node.find(name)
    mode, count = "constant", -1
    if child is not None:
        t, r = child.find("Type"), child.find("Repetition")
        code = _char(data, version, t) if t is not None and t.props and isinstance(t.props[0], bool) else None
        if code is None and t is not None and t.props and isinstance(t.props[0], int):
            code = int(t.props[0])
        if code is not None:
            mode = EXTRAPOLATION.get(code, "constant")
            if r is not None and r.props and isinstance(r.props[0], int):
                count = max(int(r.props[0]), -1)
    return mode, count


def read_curve(
    path: Path,
    node: Node,
    ktps: int,
    max_value: float,
    raw: bytes = b"",
    version: int = 7400,
    max_ticks: int = 2**62,
) -> Curve:
    """The curve of an ``AnimationCurve`` record (ParseError naming the curve when its
    arrays disagree); ``raw``: the file's bytes (for the extrapolation letters), ``version``
    the FBX version; key times beyond +-``max_ticks`` KTime ticks are refused."""
    what = f"AnimationCurve {node.props[0] if node.props else '?'}"
    times, vals = _array(node, "KeyTime"), _array(node, "KeyValueFloat")
    if times is None or vals is None:
        raise ParseError(path, None, f"{what}: expected KeyTime and KeyValueFloat arrays")
    if len(times) != len(vals) or len(times) == 0:
        raise ParseError(
            path, None, f"{what}: expected as many key values as key times (>= 1), found {len(vals)} and {len(times)}"
        )
    if times.dtype.kind not in "iu" or times.min() < -max_ticks or times.max() > max_ticks:
        raise ParseError(
            path, None, f"{what}: expected integer key times (KTime ticks) within +-{max_ticks:,}, found {times.dtype}"
        )
    ticks = times.astype(np.int64)
    if np.any(np.diff(ticks) <= 0):
        raise ParseError(path, None, f"{what}: expected strictly increasing key times")
    values = vals.astype(np.float64)
    if not np.all(np.abs(values) <= max_value):
        raise ParseError(path, None, f"{what}: expected finite key values within {max_value:g}")
    n = len(ticks)
    flags_a, data_a, refs_a = (
        _array(node, "KeyAttrFlags"),
        _array(node, "KeyAttrDataFloat"),
        _array(node, "KeyAttrRefCount"),
    )
    if flags_a is None or refs_a is None or data_a is None:  # no attributes: linear keys (older writers)
        flags = np.full(n, LINEAR, dtype=np.uint32)
        data = np.zeros((n, 4), dtype=np.float32)
    else:
        refs = refs_a.astype(np.int64)
        if len(flags_a) != len(refs) or len(data_a) != 4 * len(refs) or np.any(refs <= 0) or refs.sum(initial=0) < n:
            raise ParseError(
                path,
                None,
                f"{what}: expected KeyAttrFlags, KeyAttrDataFloat (4 per run) and KeyAttrRefCount covering "
                f"{n} keys, found {len(flags_a)}, {len(data_a)} and {len(refs)} runs of {int(refs.sum(initial=0))} keys",
            )
        run = np.repeat(np.arange(len(refs)), refs)[:n]
        flags = flags_a.astype(np.int64).astype(np.uint32)[run]
        data = np.asarray(data_a, dtype=np.float32).reshape(-1, 4)[run]
    if not np.all(np.isfinite(data[:, :2])) or not np.all(np.abs(data[:, :2]) <= max_value * 1e3):
        raise ParseError(path, None, f"{what}: expected finite key tangents")
    curve = prepare(ticks, values, flags, data, ktps)
    curve.pre = _extrapolation(node, "Pre-Extrapolation", raw, version)
    curve.post = _extrapolation(node, "Post-Extrapolation", raw, version)
    return curve


def _auto(
    pt: np.ndarray,
    t: np.ndarray,
    nt: np.ndarray,
    pv: np.ndarray,
    v: np.ndarray,
    nv: np.ndarray,
    wl: np.ndarray,
    wr: np.ndarray,
    bias: np.ndarray,
    flags: np.ndarray,
) -> np.ndarray:
    """Auto tangent slope of interior keys (arrays), the SDK's rule."""
    slope = (nv - pv) / (nt - pt)
    dep = (flags & TIME_INDEPENDENT) == 0
    sl = (v - pv) / (t - pt)
    sr = (nv - v) / (nt - t)
    delta = (t - pt) / (nt - pt)
    blended = slope * 0.5 + (sl * (1.0 - delta) + sr * delta) * 0.5
    bw = np.abs(bias) / 100.0
    target = np.where(bias > 0.0, sr, sl)
    bdelta = target - blended
    biased = np.where(bw > 0.0001, blended * (1.0 - bw) + target * bw, blended)
    abw = bw - 5.0
    sign = np.where(np.abs(bdelta) > 0.00001, bdelta, bias)
    sign = np.where(sign > 0.0, 1.0, -1.0)
    biased = np.where((bw > 0.0001) & (abw > 0.0), biased + abw * abw * sign * 40.0, biased)
    slope = np.where(dep, biased, slope)
    prog = (flags & CLAMP_PROGRESSIVE) != 0
    s_sign = np.where(slope >= 0.0, 1.0, -1.0)
    abs_slope = s_sign * slope
    rl, rr = wl * (t - pt), wr * (nt - t)
    with np.errstate(divide="ignore", invalid="ignore"):
        ml = np.where(rl > 0.0, s_sign * (v - pv) / rl, 0.0)
        mr = np.where(rr > 0.0, s_sign * (nv - v) / rr, 0.0)
    ml = np.where(ml > 0.0, ml, 0.0)
    mr = np.where(mr > 0.0, mr, 0.0)
    clamped = s_sign * np.minimum(np.minimum(abs_slope, ml), mr)
    slope = np.where(prog, clamped, slope)
    clamp = ((flags & CLAMP) != 0) & (np.minimum(np.abs(pv - v), np.abs(nv - v)) <= 0.0)
    return np.where(clamp, 0.0, slope).astype(np.float32)


def _auto_edge(d0: np.ndarray, d1: np.ndarray, dv: np.ndarray, bias: np.ndarray, flags: np.ndarray) -> np.ndarray:
    """Auto tangent slope of a first or last key: the slope to its one neighbour."""
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = dv / (d1 - d0)
    abw = np.abs(bias) / 100.0 - 5.0
    add = np.where(abw > 0.0, abw * abw * np.where(bias > 0.0, 1.0, -1.0) * 40.0, 0.0)
    slope = np.where((flags & TIME_INDEPENDENT) == 0, slope + add, slope)
    zero = ((flags & CLAMP_PROGRESSIVE) != 0) | (((flags & CLAMP) != 0) & (np.abs(dv) <= 0.0))
    return np.where(zero, 0.0, slope).astype(np.float32)


def prepare(ticks: np.ndarray, values: np.ndarray, flags: np.ndarray, data: np.ndarray, ktps: int) -> Curve:
    """Solve the tangents of keys (vectorised): per-key ``flags`` (uint32) and ``data``
    (K, 4) float32 expanded from the run-length encoding."""
    n = len(ticks)
    t = ticks.astype(np.float64) / float(ktps)
    v = values.astype(np.float64)
    flags = flags.astype(np.int64)
    raw_r, raw_nl = data[:, 0].astype(np.float32), data[:, 1].astype(np.float32)
    packed = data[:, 2].astype(np.float32).view(np.uint32).astype(np.int64)
    w_r = np.where(flags & WEIGHTED_RIGHT, (packed & 0xFFFF).astype(np.float32) * np.float32(0.0001), _THIRD)
    w_nl = np.where(flags & WEIGHTED_NEXT_LEFT, (packed >> 16).astype(np.float32) * np.float32(0.0001), _THIRD)
    w_r, w_nl = w_r.astype(np.float32), w_nl.astype(np.float32)
    nxt_t = np.append(t[1:], t[-1])
    nxt_v = np.append(v[1:], v[-1])
    prv_t = np.insert(t[:-1], 0, 0.0)
    prv_v = np.insert(v[:-1], 0, v[0])
    has_next = np.arange(n) + 1 < n
    has_prev = np.arange(n) > 0
    const = (flags & CONSTANT) != 0
    cubic = ~const & ((flags & CUBIC) != 0)
    if not const.any() and not cubic.any():
        return _linear(ticks, t, v, ktps)
    linear = ~const & ~cubic
    tcb = cubic & ((flags & TANGENT_TCB) != 0)
    user = cubic & ~tcb & ((flags & TANGENT_USER) != 0)
    auto = cubic & ~tcb & ~user
    with np.errstate(divide="ignore", invalid="ignore"):
        lin_slope = np.where(has_next & (nxt_t > t), (nxt_v - v) / (nxt_t - t), 0.0).astype(np.float32)
    # what each key hands to the next key's left side
    nl_slope = np.where(const | tcb, np.float32(0.0), np.where(linear, lin_slope, raw_nl)).astype(np.float32)
    nl_weight = np.where(const | tcb | linear, _THIRD, w_nl).astype(np.float32)
    w_r = np.where(const | linear, _THIRD, w_r).astype(np.float32)
    sl_in = np.insert(nl_slope[:-1], 0, np.float32(0.0)).astype(np.float32)
    wl_in = np.insert(nl_weight[:-1], 0, _THIRD).astype(np.float32)
    slope_l = sl_in.copy()
    slope_r = np.where(const, np.float32(0.0), np.where(linear, lin_slope, raw_r)).astype(np.float32)
    # TCB: tension, continuity, bias in the data floats
    if tcb.any():
        with np.errstate(divide="ignore", invalid="ignore"):
            tl = np.where(has_prev & (t > prv_t), (v - prv_v) / (t - prv_t), 0.0)
            tr = np.where(has_next & (nxt_t > t), (nxt_v - v) / (nxt_t - t), 0.0)
        edge = ~(has_prev & (t > prv_t)) | ~(has_next & (nxt_t > t))
        factor = np.where(edge, 1.0, 0.5)
        ten, con, bia = (data[:, k].astype(np.float64) for k in range(3))
        d00 = factor * (1 - ten) * (1 + bia) * (1 - con)
        d01 = factor * (1 - ten) * (1 - bia) * (1 + con)
        d10 = factor * (1 - ten) * (1 + bia) * (1 + con)
        d11 = factor * (1 - ten) * (1 - bia) * (1 - con)
        slope_l = np.where(tcb, (d00 * tl + d01 * tr).astype(np.float32), slope_l)
        slope_r = np.where(tcb, (d10 * tl + d11 * tr).astype(np.float32), slope_r)
    if auto.any():
        inner = auto & has_prev & has_next & (t > prv_t) & (nxt_t > t)
        left_only = auto & ~inner & has_prev & (t > prv_t)
        right_only = auto & ~inner & ~left_only & has_next & (nxt_t > t)
        alone = auto & ~inner & ~left_only & ~right_only
        with np.errstate(divide="ignore", invalid="ignore"):
            sl64, sr64 = sl_in.astype(np.float64), slope_r.astype(np.float64)
            wl64, wr64 = wl_in.astype(np.float64), w_r.astype(np.float64)
            a_r = _auto(prv_t, t, nxt_t, prv_v, v, nxt_v, wl64, wr64, sr64, flags)
            a_l = _auto(prv_t, t, nxt_t, prv_v, v, nxt_v, wl64, wr64, -sl64, flags)
            e_l = _auto_edge(prv_t, t, v - prv_v, -sl64, flags)
            e_r = _auto_edge(t, nxt_t, nxt_v - v, sr64, flags)
        unified = np.abs(sl_in + slope_r) <= np.float32(0.0001)
        new_l = np.where(unified, a_r, a_l)
        slope_l = np.where(inner, new_l, np.where(left_only, e_l, np.where(right_only, e_r, slope_l)))
        slope_r = np.where(inner, a_r, np.where(left_only, e_l, np.where(right_only, e_r, slope_r)))
        slope_l = np.where(alone, np.float32(0.0), slope_l).astype(np.float32)
        slope_r = np.where(alone, np.float32(0.0), slope_r).astype(np.float32)
    left_dx = np.where(t > prv_t, (wl_in.astype(np.float64) * (t - prv_t)).astype(np.float32), np.float32(0.0))
    right_dx = np.where(nxt_t > t, (w_r.astype(np.float64) * (nxt_t - t)).astype(np.float32), np.float32(0.0))
    left_dy = (left_dx * slope_l).astype(np.float32)
    right_dy = (right_dx * slope_r).astype(np.float32)
    kind = np.where(const, np.where(flags & CONSTANT_NEXT, K_NEXT, K_PREV), np.where(cubic, K_CUBIC, K_LINEAR)).astype(
        np.int8
    )
    return Curve(
        ticks=ticks,
        times=t,
        values=v,
        kind=kind,
        left_dx=left_dx,
        left_dy=left_dy,
        right_dx=right_dx,
        right_dy=right_dy,
        pre=("constant", -1),
        post=("constant", -1),
        ktps=ktps,
    )


def _linear(ticks: np.ndarray, t: np.ndarray, v: np.ndarray, ktps: int) -> Curve:
    """:func:`prepare` for a curve of linear keys only (baked takes): tangents along the
    segments, weights 1/3."""
    dt = np.diff(t)
    slope = (np.diff(v) / dt).astype(np.float32)  # key times strictly increase
    dx = (_THIRD.astype(np.float64) * dt).astype(np.float32)
    zero = np.zeros(1, dtype=np.float32)
    right_dx, right_dy = np.r_[dx, zero], np.r_[(dx * slope).astype(np.float32), zero]
    left_dx = np.r_[np.float32(_THIRD * t[0]) if t[0] > 0 else zero[0], dx].astype(np.float32)
    left_dy = np.r_[zero, (dx * slope).astype(np.float32)]  # the first key's incoming slope is 0
    return Curve(
        ticks=ticks,
        times=t,
        values=v,
        kind=np.full(len(t), K_LINEAR, dtype=np.int8),
        left_dx=left_dx,
        left_dy=left_dy,
        right_dx=right_dx,
        right_dy=right_dy,
        pre=("constant", -1),
        post=("constant", -1),
        ktps=ktps,
    )


def _bezier_t(p1: np.ndarray, p2: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """Parameter of a cubic Bezier in x (control x 0, p1, p2, 1) reaching ``x0``."""
    a = 3 * p1 - 3 * p2 + 1.0
    b = 3 * p2 - 6 * p1
    c = 3 * p1
    t: np.ndarray = x0.copy()
    for _ in range(11):
        x1 = ((a * t + b) * t + c) * t - x0
        d = (3 * a * t + 2 * b) * t + c
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(d != 0, x1 / d, 0.0)
        t = t - step
    return t


def _inside(c: Curve, time: np.ndarray) -> np.ndarray:
    """Values at times within [first key, last key]."""
    n = len(c.times)
    if n == 1:
        return np.full(time.shape, c.values[0])
    # a sample within SNAP of a key is taken at the key (frame times computed in floating
    # point land a rounding error either side of a key; at a step that decides the value)
    i = np.clip(np.searchsorted(c.times, time + SNAP, side="right") - 1, 0, n - 2)
    t0, t1 = c.times[i], c.times[i + 1]
    v0, v1 = c.values[i], c.values[i + 1]
    rcp = 1.0 / (t1 - t0)
    u = (time - t0) * rcp
    kind = c.kind[i]
    out = np.where(kind == K_NEXT, v1, v0)
    lin = kind == K_LINEAR
    out = np.where(lin, v0 * (1.0 - u) + v1 * u, out)
    cub = kind == K_CUBIC
    if cub.any():
        x1 = c.right_dx[i].astype(np.float64) * rcp
        x2 = 1.0 - c.left_dx[i + 1].astype(np.float64) * rcp
        s = _bezier_t(x1[cub], x2[cub], u[cub])
        s2, s3 = s * s, s * s * s
        w = 1.0 - s
        w2, w3 = w * w, w * w * w
        y0, y3 = v0[cub], v1[cub]
        y1 = y0 + c.right_dy[i][cub]
        y2 = y3 - c.left_dy[i + 1][cub]
        out[cub] = w3 * y0 + 3.0 * (w2 * s * y1 + w * s2 * y2) + s3 * y3
    exact = np.abs(time - t0) <= SNAP
    out = np.where(exact, v0, out)
    out = np.where(time >= c.times[-1], c.values[-1], out)
    return np.where(time <= c.times[0], c.values[0], out)


def evaluate(c: Curve, time: np.ndarray) -> np.ndarray:
    """Values of a curve at ``time`` (seconds), extrapolated outside its keys."""
    time = np.asarray(time, dtype=np.float64)
    if time.shape == c.times.shape and np.abs(time - c.times).max(initial=0.0) <= SNAP:
        return cast("np.ndarray", c.values.copy())  # a key on every sample (baked takes): the keys themselves
    out = _inside(c, time)
    if len(c.times) < 2:
        return out
    for pre, mask in ((True, time < c.times[0]), (False, time > c.times[-1])):
        if mask.any():
            out[mask] = _extrapolate(c, time[mask], pre)
    return out


def _extrapolate(c: Curve, time: np.ndarray, pre: bool) -> np.ndarray:
    mode, count = c.pre if pre else c.post
    k = 0 if pre else -1
    value = c.values[k]
    if mode == "constant":
        return np.full(time.shape, value)
    if mode == "slope":
        dx, dy = (c.right_dx[0], c.right_dy[0]) if pre else (c.left_dx[-1], c.left_dy[-1])
        if dx == 0:
            return np.full(time.shape, np.nan if dy != 0 else value)
        return cast("np.ndarray", value + float(dy) * ((time - c.times[k]) / float(dx)))
    if count == 0:
        return np.full(time.shape, value)
    scale = float(c.ktps)
    t0, t1 = np.rint(c.times[0] * scale), np.rint(c.times[-1] * scale)
    tt = time * scale
    delta = t0 - tt if pre else tt - t1
    duration = t1 - t0
    if not duration >= 1.0:
        return np.full(time.shape, value)
    rep = delta / duration
    rep_n = np.floor(rep)
    rep_d = delta - rep_n * duration
    if count > 0:
        over = rep_n >= count
        rep_n = np.where(over, count - 1, rep_n)
        rep_d = np.where(over, duration, rep_d)
    if mode == "mirror":
        parity = rep_n * 0.5 - np.floor(rep_n * 0.5)
        rep_d = np.where(parity <= 0.25, duration - rep_d, rep_d)
    if pre:
        rep_d = duration - rep_d
    out = _inside(c, (t0 + rep_d) / scale)
    if mode == "relative":
        dv = c.values[-1] - c.values[0]
        out = out + (-dv if pre else dv) * (rep_n + 1.0)
    return out
