"""Candidate regions for template retrieval from the inverted lists (``matchers.template`` with an index).

A template's *anchor* is a constellation of one or two of its key features of one feature
set that holds (cared for, constant) over a stretch of at least ``min_run`` template frames
and is rare in the database: the database frames where it holds are the union of the
inverted lists of every code agreeing with it (``SetIndex.union``). A path of the template
spans at most ``2 K - 1`` database frames (steps (1,2) stretch by at most 2), so every path
that passes through an anchor segment lies inside that segment widened by ``2 K`` frames on
both sides; subsequence DTW runs only there. A match whose frames never show the anchor is
missed: the benchmark reports hits lost against the full scan.
"""
from __future__ import annotations

from itertools import combinations

import numpy as np

from .features import SET_SLICES

from .template_model import MotionTemplate


def choose_anchor(t: MotionTemplate, index, max_features: int = 2, min_run: int = 3):
    """The rarest constellation of the template's key features (module doc).

    Returns ``(set name, {local bit: value}, database fraction)`` or None when no key
    feature is cared for over ``min_run`` frames.
    """
    q = t.quantized()
    best = None
    for name, sl in SET_SLICES.items():
        if name not in index.sets:
            continue
        idx = index.sets[name]
        cols = [int(c) for c in t.columns if sl.start <= c < sl.stop]
        counts = idx.list_frames
        total = max(int(idx.seg_end[-1] - idx.seg_start[0]) if idx.n_segments else 1, 1)
        for r in range(1, max_features + 1):
            for combo in combinations(cols, r):
                v = q[:, list(combo)]
                ok = np.all(v != 0.5, axis=1)
                # stretches of constant cared values over the combination
                key = np.where(ok[:, None], v, -1.0)
                brk = np.r_[True, np.any(key[1:] != key[:-1], axis=1)]
                starts = np.flatnonzero(brk)
                lens = np.diff(np.append(starts, len(key)))
                for s, n in zip(starts, lens):
                    if n < min_run or not ok[s]:
                        continue
                    bits = {c - sl.start: int(v[s, i]) for i, c in enumerate(combo)}
                    sel = np.ones(len(idx.list_codes), bool)
                    for b, val in bits.items():
                        sel &= ((idx.list_codes >> b) & 1) == val
                    frac = counts[sel].sum() / total
                    if best is None or frac < best[2]:
                        best = (name, bits, float(frac))
    return best


def candidate_ranges(t: MotionTemplate, index, max_features: int = 2, min_run: int = 3) -> tuple[np.ndarray, float]:
    """Frame ranges ``(R, 2)`` (global, each inside one clip) to search, and the fraction of
    the database they cover (1.0 and the whole clips when the template has no anchor)."""
    any_set = next(iter(index.sets.values()))
    offsets = any_set.clip_offsets
    whole = np.stack([offsets[:-1], offsets[1:]], axis=1)
    anchor = choose_anchor(t, index, max_features, min_run)
    if anchor is None:
        return whole, 1.0
    name, bits, _ = anchor
    idx = index.sets[name]
    sel = np.ones(len(idx.list_codes), bool)
    for b, val in bits.items():
        sel &= ((idx.list_codes >> b) & 1) == val
    pos = idx.union(idx.list_codes[sel])
    if not len(pos):
        return np.zeros((0, 2), np.int64), 0.0
    width = 2 * t.n_frames
    clip = idx.seg_clip[pos]
    lo = np.maximum(idx.seg_start[pos] - width, offsets[clip])
    hi = np.minimum(idx.seg_end[pos] + width, offsets[clip + 1])
    # merge overlapping ranges of one clip (positions, hence lo within a clip, are sorted)
    run_hi = np.maximum.accumulate(hi)
    new = np.r_[True, (lo[1:] > run_hi[:-1]) | (clip[1:] != clip[:-1])]
    first = np.flatnonzero(new)
    ranges = np.stack([lo[first], np.maximum.reduceat(hi, first)], axis=1)
    ranges = ranges[ranges[:, 1] - ranges[:, 0] >= max(t.n_frames // 2, 1)]
    return ranges.astype(np.int64), float((ranges[:, 1] - ranges[:, 0]).sum() / max(int(offsets[-1]), 1))


__all__ = ["candidate_ranges", "choose_anchor"]
