"""Slow, obviously correct FBX curve evaluation: the twin of ``plugins/formats/_fbx_curves.py``.

One key at a time, in the order the FBX SDK (and ufbx) walk them: each key's flags decide
its segment's interpolation and its tangents, the left tangent coming from what the
previous key handed on. Evaluation scans the keys for each time and bisects the cubic
Bezier's time parameter (no Newton steps), so it shares no arithmetic with the fast path.
"""

from __future__ import annotations

import math

import numpy as np

THIRD = float(np.float32(0.333333))


def f32(x: float) -> float:
    return float(np.float32(x))


def _auto(pt, t, nt, pv, v, nv, wl, wr, bias, flags):
    if flags & 0x1000 and min(abs(pv - v), abs(nv - v)) <= 0.0:
        return 0.0
    slope = (nv - pv) / (nt - pt)
    if not flags & 0x2000:
        sl, sr = (v - pv) / (t - pt), (nv - v) / (nt - t)
        d = (t - pt) / (nt - pt)
        slope = slope * 0.5 + (sl * (1 - d) + sr * d) * 0.5
        bw = abs(bias) / 100.0
        if bw > 0.0001:
            target = sr if bias > 0 else sl
            bdelta = target - slope
            slope = slope * (1 - bw) + target * bw
            a = bw - 5.0
            if a > 0:
                sign = bdelta if abs(bdelta) > 0.00001 else bias
                slope += a * a * (1.0 if sign > 0 else -1.0) * 40.0
    if flags & 0x4000:
        sign = 1.0 if slope >= 0 else -1.0
        mag = sign * slope
        rl, rr = wl * (t - pt), wr * (nt - t)
        ml = sign * (v - pv) / rl if rl > 0 else 0.0
        mr = sign * (nv - v) / rr if rr > 0 else 0.0
        mag = min(mag, max(ml, 0.0), max(mr, 0.0))
        slope = sign * mag
    return f32(slope)


def _edge(t0, t1, dv, bias, flags):
    if flags & 0x4000 or (flags & 0x1000 and abs(dv) <= 0.0):
        return 0.0
    slope = dv / (t1 - t0)
    if not flags & 0x2000:
        a = abs(bias) / 100.0 - 5.0
        if a > 0:
            slope += a * a * (1.0 if bias > 0 else -1.0) * 40.0
    return f32(slope)


def keys(times, values, flags, data):
    """Per key: (time, value, kind, left dx, left dy, right dx, right dy); kind one of
    'prev', 'next', 'linear', 'cubic'. ``data``: (K, 4) float32."""
    n = len(times)
    out = []
    slope_left, weight_left, prev_time = 0.0, THIRD, 0.0
    for i in range(n):
        t, v, fl = float(times[i]), float(values[i]), int(flags[i])
        nt = float(times[i + 1]) if i + 1 < n else t
        a0, a1 = float(data[i][0]), float(data[i][1])
        packed = int(np.float32(data[i][2]).view(np.uint32))
        slope_right, weight_right, next_slope_left, next_weight_left = a0, THIRD, a1, THIRD
        if fl & 0x1000000:
            weight_right = f32(np.float32(packed & 0xFFFF) * np.float32(0.0001))
        if fl & 0x2000000:
            next_weight_left = f32(np.float32(packed >> 16) * np.float32(0.0001))
        if fl & 0x2:
            kind = "next" if fl & 0x100 else "prev"
            weight_right = next_weight_left = THIRD
            slope_right = next_slope_left = 0.0
        elif fl & 0x8:
            kind = "cubic"
            if fl & 0x200:
                edge = False
                tl = tr = 0.0
                if i > 0 and t > prev_time:
                    tl = (v - float(values[i - 1])) / (t - prev_time)
                else:
                    edge = True
                if i + 1 < n and nt > t:
                    tr = (float(values[i + 1]) - v) / (nt - t)
                else:
                    edge = True
                f = 1.0 if edge else 0.5
                ten, con, bia = (float(data[i][k]) for k in range(3))
                slope_left = f32(
                    f * (1 - ten) * (1 + bia) * (1 - con) * tl + f * (1 - ten) * (1 - bia) * (1 + con) * tr
                )
                slope_right = f32(
                    f * (1 - ten) * (1 + bia) * (1 + con) * tl + f * (1 - ten) * (1 - bia) * (1 - con) * tr
                )
                next_slope_left, next_weight_left = 0.0, THIRD
            elif fl & 0x400:
                pass
            else:
                pv = float(values[i - 1]) if i > 0 else v
                nv = float(values[i + 1]) if i + 1 < n else v
                if i > 0 and i + 1 < n and t > prev_time and nt > t:
                    if abs(f32(slope_left + slope_right)) <= f32(0.0001):
                        slope_left = slope_right = _auto(
                            prev_time, t, nt, pv, v, nv, weight_left, weight_right, slope_right, fl
                        )
                    else:
                        sl = _auto(prev_time, t, nt, pv, v, nv, weight_left, weight_right, -slope_left, fl)
                        slope_right = _auto(prev_time, t, nt, pv, v, nv, weight_left, weight_right, slope_right, fl)
                        slope_left = sl
                elif i > 0 and t > prev_time:
                    slope_left = slope_right = _edge(prev_time, t, v - pv, -slope_left, fl)
                elif i + 1 < n and nt > t:
                    slope_left = slope_right = _edge(t, nt, nv - v, slope_right, fl)
                else:
                    slope_left = slope_right = 0.0
        else:
            kind = "linear"
            weight_right = next_weight_left = THIRD
            s = f32((float(values[i + 1]) - v) / (nt - t)) if nt > t else 0.0
            slope_right = next_slope_left = s
        ldx = f32(weight_left * (t - prev_time)) if t > prev_time else 0.0
        rdx = f32(weight_right * (nt - t)) if nt > t else 0.0
        out.append((t, v, kind, ldx, f32(ldx * f32(slope_left)), rdx, f32(rdx * f32(slope_right))))
        slope_left, weight_left, prev_time = next_slope_left, next_weight_left, t
    return out


def value_inside(ks, time):
    if time <= ks[0][0]:
        return ks[0][1]
    if time >= ks[-1][0]:
        return ks[-1][1]
    for a, b in zip(ks, ks[1:], strict=False):
        if a[0] <= time < b[0]:
            break
    if time == a[0]:
        return a[1]
    u = (time - a[0]) / (b[0] - a[0])
    if a[2] == "prev":
        return a[1]
    if a[2] == "next":
        return b[1]
    if a[2] == "linear":
        return a[1] * (1 - u) + b[1] * u
    h = b[0] - a[0]
    px = [0.0, a[5] / h, 1.0 - b[3] / h, 1.0]
    py = [a[1], a[1] + a[6], b[1] - b[4], b[1]]

    def bez(p, s):
        return (1 - s) ** 3 * p[0] + 3 * (1 - s) ** 2 * s * p[1] + 3 * (1 - s) * s * s * p[2] + s**3 * p[3]

    lo, hi = 0.0, 1.0
    for _ in range(200):  # x(s) is monotonic for valid handles
        mid = 0.5 * (lo + hi)
        if bez(px, mid) < u:
            lo = mid
        else:
            hi = mid
    return bez(py, 0.5 * (lo + hi))


def value(ks, time, pre=("constant", -1), post=("constant", -1), ktps=46_186_158_000):
    first, last = ks[0], ks[-1]
    if len(ks) < 2 or first[0] <= time <= last[0]:
        return value_inside(ks, time)
    is_pre = time < first[0]
    mode, count = pre if is_pre else post
    key = first if is_pre else last
    if mode == "constant" or (mode != "slope" and count == 0):
        return key[1]
    if mode == "slope":
        dx, dy = (key[5], key[6]) if is_pre else (key[3], key[4])
        return key[1] + dy * (time - key[0]) / dx
    t0, t1 = round(first[0] * ktps), round(last[0] * ktps)
    delta = (t0 - time * ktps) if is_pre else (time * ktps - t1)
    dur = t1 - t0
    n_rep = math.floor(delta / dur)
    d = delta - n_rep * dur
    if count > 0 and n_rep >= count:
        n_rep, d = count - 1, dur
    if mode == "mirror" and (n_rep % 2) == 0:
        d = dur - d
    if is_pre:
        d = dur - d
    out = value_inside(ks, (t0 + d) / ktps)
    if mode == "relative":
        dv = last[1] - first[1]
        out += (-dv if is_pre else dv) * (n_rep + 1)
    return out
