"""The inverted-list anchor pre-filter that ``matchers.template`` used up to this release (it
lost true hits: not admissible), kept here only as the same-run speed baseline of
``benchmarks/templates.py`` (target: the default within 1.5x of it)."""

from __future__ import annotations

from itertools import combinations

import numpy as np

from mocapflow.plugins.relational.features import SET_SLICES
from mocapflow.plugins.relational.template_model import MotionTemplate


def choose_anchor(
    t: MotionTemplate, index, max_features: int = 2, min_run: int = 3, sets: tuple[str, ...] | None = None
):
    """The rarest constellation of the template's key features (module doc).

    Returns ``(set name, {local bit: value}, database fraction, (a, b))`` with ``a..b`` the
    template frames of the stretch (inclusive), or None when no key feature is cared for
    over ``min_run`` frames. Of equally rare constellations the longest stretch is taken.
    """
    q = t.quantized()
    best = None
    for name, sl in SET_SLICES.items():
        if name not in index.sets or (sets is not None and name not in sets):
            continue
        idx = index.sets[name]
        cols = [int(c) for c in t.columns if sl.start <= c < sl.stop]
        counts = idx.list_frames
        total = max(int(idx.seg_end[-1] - idx.seg_start[0]) if idx.n_segments else 1, 1)
        list_bits = {c: ((idx.list_codes >> (c - sl.start)) & 1).astype(np.int64) for c in cols}
        for r in range(1, max_features + 1):
            for combo in combinations(cols, r):
                # frames per value of the combination's bits (value i of bit c at bit position i)
                hist = np.bincount(
                    sum(list_bits[c] << i for i, c in enumerate(combo)), weights=counts, minlength=1 << r
                )
                v = q[:, list(combo)]
                ok = np.all(v != 0.5, axis=1)
                # stretches of constant cared values over the combination
                key = np.where(ok[:, None], v, -1.0)
                brk = np.r_[True, np.any(key[1:] != key[:-1], axis=1)]
                starts = np.flatnonzero(brk)
                lens = np.diff(np.append(starts, len(key)))
                for s, n in zip(starts, lens, strict=True):
                    if n < min_run or not ok[s]:
                        continue
                    bits = {c - sl.start: int(v[s, i]) for i, c in enumerate(combo)}
                    frac = float(hist[sum(int(v[s, i]) << i for i in range(r))] / total)
                    run = (int(s), int(s + n - 1))
                    if best is None or (frac, -n) < (best[2], -(best[3][1] - best[3][0] + 1)):
                        best = (name, bits, frac, run)
    return best


def candidate_ranges(t: MotionTemplate, index, max_features: int = 2, min_run: int = 3) -> tuple[np.ndarray, float]:
    """Frame ranges ``(R, 2)`` (global, each inside one clip) to search, and the fraction of
    the database they cover (1.0 and the whole clips when the template has no anchor)."""
    any_set = next(iter(index.sets.values()))
    offsets = any_set.clip_offsets
    anchor = choose_anchor(t, index, max_features, min_run)
    if anchor is None:
        return np.stack([offsets[:-1], offsets[1:]], axis=1), 1.0
    ranges = _anchor_ranges(t, index, anchor, offsets)
    ranges = ranges[ranges[:, 1] - ranges[:, 0] >= max(t.n_frames // 2, 1)]
    return ranges.astype(np.int64), float((ranges[:, 1] - ranges[:, 0]).sum() / max(int(offsets[-1]), 1))


def _anchor_ranges(t: MotionTemplate, index, anchor, offsets: np.ndarray) -> np.ndarray:
    """Merged, sorted ranges (R, 2) around the segments where one anchor holds."""
    name, bits, _, _ = anchor
    idx = index.sets[name]
    sel = np.ones(len(idx.list_codes), bool)
    for bit, val in bits.items():
        sel &= ((idx.list_codes >> bit) & 1) == val
    pos = idx.union(idx.list_codes[sel])
    if not len(pos):
        return np.zeros((0, 2), np.int64)
    k = t.n_frames
    clip = idx.seg_clip[pos]
    lo = np.maximum(idx.seg_start[pos] - 2 * k, offsets[clip])
    hi = np.minimum(idx.seg_end[pos] + 2 * k, offsets[clip + 1])
    # merge overlapping ranges of one clip (positions, hence lo within a clip, are sorted)
    run_hi = np.maximum.accumulate(hi)
    new = np.r_[True, (lo[1:] > run_hi[:-1]) | (clip[1:] != clip[:-1])]
    first = np.flatnonzero(new)
    return np.stack([lo[first], np.maximum.reduceat(hi, first)], axis=1).astype(np.int64)


__all__ = ["candidate_ranges", "choose_anchor"]
