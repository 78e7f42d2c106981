"""Repair of the calibrated cleaner: only the runs the test flagged, bounded, never away
from the consensus (:func:`repair_flagged`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from mocapflow.framework import quaternions as quat

from .cues import acceleration, chain_columns, mirror, mirror_gain


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Half-open [start, end) runs of True in a 1-D mask."""
    if not mask.any():
        return []
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


def _edge_roughness(q: np.ndarray, cols: np.ndarray, a: int, b: int) -> float:
    """Summed acceleration (radians) of the ``cols`` joints on the frames that bound ``[a, b)``."""
    total = 0.0
    for f in (a - 1, a, b - 1, b):
        if 1 <= f < len(q) - 1:
            total += float(acceleration(q[f - 1 : f + 2][:, cols])[1].sum())
    return total


def _swapped(q: np.ndarray, lc: np.ndarray, rc: np.ndarray, a: int, b: int) -> np.ndarray:
    back: np.ndarray = q.copy()
    back[a:b, lc] = mirror(q[a:b, rc])
    back[a:b, rc] = mirror(q[a:b, lc])
    return back


def _merge(runs: list[tuple[int, int]], gap: int) -> list[tuple[int, int]]:
    out: list[list[int]] = []
    for a, b in runs:
        if out and a - out[-1][1] <= gap:
            out[-1][1] = b
        else:
            out.append([a, b])
    return [(a, b) for a, b in out]


def swap_frames(
    q: np.ndarray,
    mean_q: np.ndarray,
    joints: Sequence[str],
    flags: np.ndarray,
    swap_gain: float,
    slack: int = 8,
    skip: list[Any] | None = None,
) -> list[tuple[np.ndarray, np.ndarray, int, int]]:
    """(left columns, right columns, start, end) of the runs to swap back: runs (gaps up to
    ``slack`` merged) of a mirror gain above ``swap_gain`` radians holding a flagged chain
    cell, their ends moved by up to ``slack`` frames to where the swapped-back chains are
    smoothest, kept when then smoother at both ends than the take (a mislabelling starts and
    stops with a jump; a clean limb that resembles its mirror has none)."""
    out = []
    gain = mirror_gain(q, mean_q, joints)
    t = len(q)
    for lc, rc in chain_columns(list(joints)):
        cols = np.concatenate([lc, rc])
        for a0, b0 in _merge(_runs(gain[:, cols].max(axis=1) > swap_gain), slack):
            if not flags[a0:b0][:, cols].any():
                continue
            if skip and any(lc[0] == l2[0] and a0 < b2 + slack and a2 < b0 + slack for l2, _, a2, b2 in skip):
                continue  # an edge swap of this chain pair is there already
            best = None
            for a in range(max(0, a0 - slack), min(a0 + slack, b0 - 1) + 1):
                for b in range(max(a + 1, b0 - slack), min(t, b0 + slack) + 1):
                    lo = max(0, a - 2)
                    # the window around [a, b) only: the same as swapping the whole take, without its copy
                    back = quat.make_continuous(
                        _swapped(q[lo : min(t, b + 2)], lc, rc, a - lo, b - lo)[:, cols], axis=0
                    )
                    after = _edge_roughness(back, np.arange(len(cols)), a - lo, b - lo)
                    if best is None or after < best[0]:
                        best = (after, a, b)
            if best is None:  # no window fits (cannot happen for a0 < b0 <= t)
                continue
            after, a, b = best
            if after < _edge_roughness(q, cols, a, b):
                out.append((lc, rc, a, b))
    return out


def _swap_runs(res: Any, swap_flags: np.ndarray) -> list[Any]:
    """Swapped intervals holding a ``swap``-flagged chain cell: found by their edges
    (:func:`.swaps.swap_edges`) or by the mirror gain (:func:`swap_frames`)."""
    from .constants import SWAP_GAIN, SWAP_LEVEL, SWAP_MAX
    from .swaps import swap_edges

    q, mean_q = res.texture.q, res.mean_texture
    swaps = []
    for lc, rc, a, b in swap_edges(q, res.joints, SWAP_LEVEL, max_len=SWAP_MAX):
        if swap_flags[a:b][:, np.concatenate([lc, rc])].any():
            swaps.append((lc, rc, a, b))
    for lc, rc, a, b in swap_frames(q, mean_q, res.joints, swap_flags, SWAP_GAIN, skip=swaps):
        if not any(lc[0] == l2[0] and a < b2 and a2 < b for l2, _, a2, b2 in swaps):
            swaps.append((lc, rc, a, b))
    return swaps


def _hold_interval(length: np.ndarray, edge: np.ndarray, a: int, b: int) -> tuple[int, int] | None:
    """The still interval ``[h0, h1]`` of one joint (hold ``length`` > 0) that the run
    ``[a, b)`` touches first, when it lies inside the take with a frame on each side."""
    still = np.flatnonzero(length[a:b] > 0)
    if not len(still) or edge[a + still[0]]:
        return None
    h0 = h1 = a + int(still[0])
    while h0 > 0 and length[h0 - 1] > 0:
        h0 -= 1
    while h1 < len(length) - 1 and length[h1 + 1] > 0:
        h1 += 1
    if h0 > 0 and h1 + 1 < len(length) and h1 + 1 - h0 >= 2:
        return h0, h1
    return None


def _bounded(res: Any, q: np.ndarray, new: np.ndarray, exempt: np.ndarray) -> np.ndarray:
    """``new`` with every cell outside ``exempt`` kept only nearer the consensus and moved at
    most its digression plus the KNN spread (shortened along the geodesic)."""
    mean_q = res.mean_texture
    before = quat.geodesic_angle(q, mean_q)
    worse = (quat.geodesic_angle(new, mean_q) >= before - 1e-9) & ~exempt
    new[worse] = q[worse]
    edit = quat.geodesic_angle(new, q)
    limit = before + np.asarray(res.spread if res.spread is not None else 0.0)
    over = (edit > limit + 1e-9) & ~exempt
    if over.any():
        new[over] = quat.slerp(q[over], new[over], limit[over] / edit[over])
    return new


def repair_flagged(res: Any, flags: np.ndarray, det: np.ndarray, stat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Repaired texture (T, m, 4) and the changed cells (T, m): every flagged run (runs of
    one joint at most :data:`.constants.MERGE_GAP` frames apart merged) repaired by the
    detector ``det`` (T, m, index of :data:`.detectors.DETECTORS`) of its strongest cell
    (``stat``): ``swap`` swaps the chain pair back over the swapped interval holding it
    (:func:`_swap_runs`, kept when the swap-back is smoother at both ends), ``hold`` fills
    the still interval holding it from the consensus (:func:`.holds.consensus_fill`), others
    take an offset out when the run's ends are two agreeing jumps (:func:`_offset_run`) or
    the median KNN word joined at both ends (:func:`_displaced`). Bounds
    (:func:`_bounded`): a cell moves only nearer the consensus, by at most its digression
    plus the KNN spread (swaps, holds and offsets are verified by their edges)."""
    from ..paper.repair import _propose
    from .constants import MERGE_GAP, OFFSET_LEVEL
    from .cues import hold_lengths, speed
    from .detectors import DETECTORS
    from .holds import consensus_fill

    q = res.texture.q
    mean_q = res.mean_texture
    t_count, m = q.shape[:2]
    new = q.copy()
    exempt = np.zeros((t_count, m), bool)
    offset = np.zeros((t_count, m), bool)
    if not flags.any():
        return new, exempt
    i_swap, i_hold = DETECTORS.index("swap"), DETECTORS.index("hold")
    runs = []
    for j in np.flatnonzero(flags.any(axis=0)):
        for a, b in _merge(_runs(flags[:, j]), MERGE_GAP):
            k = a + int(np.argmax(np.where(flags[a:b, j], stat[a:b, j], -np.inf)))
            runs.append((j, a, b, int(det[k, j])))
    swap_flags = flags & (det == i_swap)
    for lc, rc, a, b in _swap_runs(res, swap_flags) if swap_flags.any() else []:
        new[a:b, lc] = mirror(q[a:b, rc])
        new[a:b, rc] = mirror(q[a:b, lc])
        exempt[a:b, np.concatenate([lc, rc])] = True
    length, edge = hold_lengths(speed(q))
    rest = np.zeros((t_count, m), bool)
    for j, a, b, d in runs:
        if exempt[a:b, j].any():
            continue
        hold = _hold_interval(length[:, j], edge[:, j], a, b) if d == i_hold else None
        if hold is not None:
            h0, h1 = hold
            new[h0 + 1 : h1 + 1, j] = consensus_fill(q[:, j], mean_q[:, j], h0, h1 + 1)
            exempt[h0 + 1 : h1 + 1, j] = True
        else:
            rest[a:b, j] = True
    if rest.any() and res.neighbours:
        around = rest.copy()
        around[1:] |= rest[:-1]
        around[:-1] |= rest[1:]
        proposal = np.full((t_count, m, 4), np.nan)
        n = res.neighbours[0].warped.shape[3]
        for neigh in res.neighbours:
            _propose(neigh, n, q, around, proposal, res, ())
        for j in np.flatnonzero(rest.any(axis=0)):
            for a, b in _runs(rest[:, j]):
                if not _offset_run(q, mean_q, new, int(j), a, b, OFFSET_LEVEL, offset):
                    _displaced(q[:, j], proposal[:, j], new[:, j], a, b)
    new = _bounded(res, q, new, exempt | offset)
    return new, np.any(new != q, axis=-1)


def _offset_run(
    q: np.ndarray, mean_q: np.ndarray, new: np.ndarray, j: int, a0: int, b0: int, level: float, offset: np.ndarray
) -> bool:
    """Repair the flagged run ``[a0, b0)`` of joint ``j`` as an offset (:mod:`.offsets`) when
    its ends are found and the repair lowers the interval's mean digression; True if done."""
    from .cues import acceleration
    from .offsets import offset_interval, remove_offset

    acc = np.median(acceleration(q[:, j : j + 1])[1:-1, 0]) if len(q) > 2 else 0.0
    found = offset_interval(q[:, j], a0, b0, max(level * 2.0 * acc, np.deg2rad(8.0)))
    if found is None:
        return False
    a, b, off_a, off_b = found
    if offset[a:b, j].any():
        return True  # an earlier run of this joint already took this interval
    rep = remove_offset(q[:, j], a, b, off_a, off_b)
    before = quat.geodesic_angle(q[a:b, j], mean_q[a:b, j]).mean()
    if quat.geodesic_angle(rep, mean_q[a:b, j]).mean() >= before:
        return False
    new[a:b, j] = rep
    offset[a:b, j] = True
    return True


def _displaced(track: np.ndarray, prop: np.ndarray, out: np.ndarray, a: int, b: int) -> None:
    """Write the KNN proposal over ``[a, b)`` into ``out``, corrected at both ends to join ``track``."""
    seg = prop[a:b]
    ok = ~np.isnan(seg[:, 0])
    if not ok.any():
        return
    t_count = len(track)
    ident = quat.identity(())

    def offset(f: int) -> np.ndarray:
        if 0 <= f < t_count and not np.isnan(prop[f, 0]):
            return quat.normalize(quat.mul(quat.conjugate(prop[f]), track[f]))
        return ident

    d0, d1 = offset(a - 1), offset(b)
    u = (np.arange(a, b) - a + 1) / (b - a + 1)
    corr = quat.slerp(np.broadcast_to(d0, (b - a, 4)), np.broadcast_to(d1, (b - a, 4)), u)
    rep = quat.normalize(quat.mul(np.where(ok[:, None], seg, track[a:b]), corr))
    rep = np.where(np.sum(rep * track[a:b], -1, keepdims=True) < 0, -rep, rep)
    out[a:b] = np.where(ok[:, None], rep, out[a:b])
