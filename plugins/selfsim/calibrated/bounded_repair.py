"""Repair of the calibrated cleaner: only flagged cells, bounded, never away from consensus.

1. Swapped limbs (mirror-cue runs that swapping back makes smoother at both ends, and the
   swaps found by their edges, :mod:`.swaps`) are swapped back exactly.
2. Other flagged runs take the median KNN word (:func:`..paper.repair._propose`) corrected
   by a displacement map slerped between the offsets at the two bounding frames, so the
   repair joins the take without a jump and keeps the word's shape; runs bounded by two
   consistent jumps are repaired as offsets (:mod:`.offsets`).
3. Bounds: a cell keeps its value unless the repair brings it nearer T̄, and an edit beyond
   the cell's digression plus its KNN spread is shortened along the geodesic.
"""

from __future__ import annotations

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
    back = q.copy()
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
    joints,
    flags: np.ndarray,
    swap_gain: float,
    slack: int = 8,
    skip: list | None = None,
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
            after, a, b = best
            if after < _edge_roughness(q, cols, a, b):
                out.append((lc, rc, a, b))
    return out


def bounded_repair(
    res,
    flags: np.ndarray,
    mirror_flags: np.ndarray,
    cap: np.ndarray,
    no_merge: np.ndarray,
    keep: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Repaired texture (T, m, 4), and (T, m) the edited, swapped and offset-repaired cells
    (offsets may lie outside ``flags``: the interval between the jumps).

    ``mirror_flags``: cells the mirror cue flagged; only runs holding one are swapped back,
    the others left as they are. ``cap`` (T, m): largest edit per cell, radians (swaps not
    capped). ``no_merge``: cells no merged gap may include. Every joint is also searched
    for offsets by their steps (:func:`.offsets.scan_offsets`) outside ``keep`` (T, m; holds
    being filled). Flagged runs of one joint at most
    :data:`.constants.MERGE_GAP` frames apart are one run (a jitter burst flags its extremes).
    """
    from ..paper.repair import _propose
    from .constants import MERGE_GAP, OFFSET_LEVEL, SWAP_GAIN, SWAP_LEVEL, SWAP_MAX
    from .swaps import swap_edges

    q = res.texture.q
    mean_q = res.mean_texture
    t_count, m = q.shape[:2]
    new = q.copy()
    swapped = np.zeros((t_count, m), bool)
    offset = np.zeros((t_count, m), bool)
    edge_swaps = swap_edges(q, res.joints, SWAP_LEVEL, max_len=SWAP_MAX)
    runs = list(edge_swaps)
    for lc, rc, a, b in swap_frames(q, mean_q, res.joints, mirror_flags, SWAP_GAIN, skip=edge_swaps):
        if not any(lc[0] == l2[0] and a < b2 and a2 < b for l2, _, a2, b2 in edge_swaps):
            runs.append((lc, rc, a, b))
    for lc, rc, a, b in runs:
        new[a:b, lc] = mirror(q[a:b, rc])
        new[a:b, rc] = mirror(q[a:b, lc])
        swapped[a:b, np.concatenate([lc, rc])] = True
    # offsets (spikes, flips) found by their two steps wherever they are, flagged or not
    _scanned_offsets(q, mean_q, new, swapped | keep, offset)
    # the mirror flags' evidence was for a swap that did not hold up: leave them
    rest = flags & ~swapped & ~mirror_flags & ~offset
    for j in np.flatnonzero(rest.any(axis=0)):
        for (_, b), (a2, _) in zip(_runs(rest[:, j])[:-1], _runs(rest[:, j])[1:], strict=True):
            if a2 - b <= MERGE_GAP and not swapped[b:a2, j].any() and not no_merge[b:a2, j].any():
                rest[b:a2, j] = True
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
                if not _offset_run(q, mean_q, new, j, a, b, OFFSET_LEVEL, offset):
                    _displaced(q[:, j], proposal[:, j], new[:, j], a, b)
    # bounds: nearer the consensus, never more than the evidence
    before = quat.geodesic_angle(q, mean_q)
    after = quat.geodesic_angle(new, mean_q)
    # an edge swap is verified by its jumps, not by T̄ (the consensus adapts to a swapped
    # limb in mid-interval): kept whole, never shortened cell by cell
    exempt = np.zeros((t_count, m), bool)
    for lc, rc, a, b in edge_swaps:
        exempt[a:b, np.concatenate([lc, rc])] = True
    exempt |= offset  # verified by its two jumps and its run's mean digression (_offset_run)
    worse = (after >= before - 1e-9) & ~exempt
    new[worse] = q[worse]
    edit = quat.geodesic_angle(new, q)
    limit = before + np.asarray(res.spread if res.spread is not None else 0.0)
    limit = np.where(swapped, limit, np.minimum(limit, cap))
    over = (edit > limit + 1e-9) & ~exempt
    if over.any():
        frac = limit[over] / edit[over]
        new[over] = quat.slerp(q[over], new[over], frac)
    edited = np.any(new != q, axis=-1)  # exact: an angle test near 0 is rounding noise
    return new, edited, swapped & edited, offset & edited


def _scanned_offsets(q: np.ndarray, mean_q: np.ndarray, new: np.ndarray, skip: np.ndarray, offset: np.ndarray) -> None:
    """Take out every offset :func:`.offsets.scan_offsets` finds on a joint (steps of
    :data:`.constants.OFFSET_LEVEL` typical accelerations, as :func:`_offset_run`) that no
    ``skip`` cell overlaps; marks them in ``offset``."""
    from .constants import OFFSET_LEVEL, OFFSET_MAX, OFFSET_SCAN_DEG
    from .cues import acceleration
    from .offsets import remove_offset, scan_offsets

    for j in range(q.shape[1]):
        acc = np.median(acceleration(q[:, j : j + 1])[1:-1, 0]) if len(q) > 2 else 0.0
        level = max(OFFSET_LEVEL * 2.0 * acc, np.deg2rad(OFFSET_SCAN_DEG))
        for a, b, off_a, off_b in scan_offsets(q[:, j], mean_q[:, j], level, OFFSET_MAX):
            if not skip[a:b, j].any():
                new[a:b, j] = remove_offset(q[:, j], a, b, off_a, off_b)
                offset[a:b, j] = True


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
