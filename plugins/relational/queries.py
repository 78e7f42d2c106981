"""Query algorithms on the inverted index (Müller, Röder, Clausen 2005, §5-§6).

Queries
-------
by example
    A clip (or a frame range of it) and a subset S of the 31 features. For each feature
    set touched by S the query's S-segmentation gives the sequence ``v_1 .. v_L``; the
    alternatives of ``v_l`` are every code of the set that agrees with ``v_l`` on S
    (``V_l = {c : c & mask == v_l}``). Selections spanning several sets are answered by
    querying each set's index and intersecting the hits (same clip, frame spans
    overlapping by ``min_overlap`` of the shorter one).
scene description (§6.3)
    Progressions of constellations (``{feature: 0/1}`` per step, omitted features are
    "*"), each answered by an adaptive fuzzy query, combined under co-occurrence
    constraints ``(progression a, step i, progression b, step j)``: those steps overlap.

Modes
-----
``exact`` (eq. 7, the selection must cover whole feature sets), ``fuzzy`` (eq. 11, the
database segmentation is kept), ``adaptive`` (§5.2, the database segmentation is coarsened
to maximal runs of each ``V_l``: exact hits for the selected features; the default) and
``mismatch`` (up to ``mismatches`` levels may disagree, optionally only at
``mismatch_positions``, on the coarsened segmentation; dynamic programming kernel).

The ranking cost of a hit is the segment-length heuristic of §6.2 (``matcher`` ranks and
refines them). Component code is in ``matcher.py``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal, cast

import numpy as np

from mocapflow.framework.errors import ConfigError

from .feature_table import SET_SLICES, feature_column, feature_set_of
from .inverted import InvertedIndex, SetIndex
from .segmentation import segment

Mode = Literal["exact", "fuzzy", "adaptive", "mismatch"]


@dataclass
class Hits:
    """Hits of one query: global frame spans, ranking cost and per-level correspondences.

    ``levels`` (n, L, 2) global database frame ranges of the query levels and
    ``query_levels`` (L, 2) query frame ranges, for single-set hits (DTW refinement).
    """

    clip: np.ndarray
    start: np.ndarray
    end: np.ndarray
    cost: np.ndarray
    levels: np.ndarray | None = None
    query_levels: np.ndarray | None = None
    sets: str = ""
    n_levels: int = 0
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.start)

    @classmethod
    def empty(cls, sets: str = "") -> Hits:
        z = np.zeros(0, np.int64)
        return cls(z, z, z, np.zeros(0), sets=sets)


def coarsen_fuzzy(member: np.ndarray) -> np.ndarray:
    """Merge adjacent fuzzy sets that intersect until neighbours are disjoint (§5.2)."""
    rows: list[np.ndarray] = []
    for row in np.asarray(member, dtype=bool):
        rows.append(row.copy())
        # a merged set may now meet the set before it: keep conjoining backwards
        while len(rows) > 1 and np.any(rows[-2] & rows[-1]):
            last = rows.pop()
            rows[-1] = rows[-1] | last
    return np.array(rows, dtype=bool).reshape(-1, np.asarray(member).shape[-1])


def subset_member(values: np.ndarray, mask: int, n_bits: int) -> np.ndarray:
    """Fuzzy sets ``V_l = {c : c & mask == values[l]}`` as a (L, 2**n_bits) boolean table."""
    codes = np.arange(1 << n_bits, dtype=np.int64)
    return cast("np.ndarray", (codes[None, :] & mask) == np.asarray(values, np.int64)[:, None])


def _level_frames(idx: SetIndex, bounds: np.ndarray) -> np.ndarray:
    """Global frame ranges (n, L, 2) of hits given segment bounds (n, L+1)."""
    return np.stack([idx.seg_start[bounds[:, :-1]], idx.seg_end[bounds[:, 1:] - 1]], axis=-1)


def search_set(
    idx: SetIndex,
    member: np.ndarray,
    mode: Mode,
    mismatches: int = 1,
    allowed: np.ndarray | None = None,
    mask: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Hits of one fuzzy query in one set index.

    ``member`` (L, 2**f) holds the fuzzy sets; ``mask`` the bits they constrain (derived
    from ``member`` when omitted), used by ``mismatch`` to coarsen the database.

    Returns ``levels`` (n, L, 2) int64, the global frame range of each query level per hit,
    and ``n_mismatch`` (n,) int64.
    """
    n_levels = len(member)
    if mode not in ("exact", "fuzzy", "adaptive", "mismatch"):
        raise ConfigError(f"unknown relational matching mode {mode!r}; choose exact, fuzzy, adaptive or mismatch")
    if mode == "adaptive":
        bounds = idx.adaptive(coarsen_fuzzy(member)) if n_levels else np.zeros((0, 1), np.int64)
        return _level_frames(idx, bounds), np.zeros(len(bounds), np.int64)
    if mode in ("exact", "fuzzy"):
        if mode == "exact":
            codes = member.argmax(axis=1)
            starts = idx.exact(codes)
        else:
            starts = idx.fuzzy(member)
        bounds = starts[:, None] + np.arange(n_levels + 1)[None, :]
        return _level_frames(idx, bounds), np.zeros(len(starts), np.int64)
    # mismatch: on the segmentation coarsened to the query's features (projected codes)
    from ._match_kernels import mismatch_scan

    proj = idx.seg_code & (_query_mask(member) if mask is None else mask)
    brk = np.r_[True, proj[1:] != proj[:-1]] | idx.clip_first
    first_seg = np.flatnonzero(brk)
    end_seg = np.append(first_seg[1:], idx.n_segments)
    allowed = np.ones(n_levels, bool) if allowed is None else np.asarray(allowed, bool)
    starts, bad = mismatch_scan(
        proj[first_seg], idx.seg_clip[first_seg], np.ascontiguousarray(member), allowed, int(mismatches)
    )
    bounds = (
        np.concatenate(
            [first_seg[starts[:, None] + np.arange(n_levels)[None, :]], end_seg[starts + n_levels - 1][:, None]], axis=1
        )
        if len(starts)
        else np.zeros((0, n_levels + 1), np.int64)
    )
    return _level_frames(idx, bounds), bad


def _query_mask(member: np.ndarray) -> int:
    """The bits a fuzzy table constrains (bits whose flip changes membership somewhere)."""
    n_bits = int(np.log2(member.shape[1]))
    codes = np.arange(member.shape[1])
    mask = 0
    for b in range(n_bits):
        if np.any(member[:, codes] != member[:, codes ^ (1 << b)]):
            mask |= 1 << b
    return mask


def example_query(
    index: InvertedIndex,
    bits: np.ndarray,
    columns: list[int],
    mode: Mode = "adaptive",
    mismatches: int = 1,
    mismatch_positions: tuple[int, ...] | None = None,
    min_overlap: float = 0.5,
) -> Hits:
    """Query by example: the query clip's boolean features and a selection of columns.

    ``bits`` (T_q, 31) are the query frames' features, ``columns`` the selected ones (0..30),
    ``mismatch_positions`` the query levels (0-based, per set) where ``mismatch`` mode may
    accept a mismatch.
    """
    parts = []
    for name, sl in SET_SLICES.items():
        cols = [c for c in columns if sl.start <= c < sl.stop]
        if not cols:
            continue
        if name not in index.sets:
            raise ConfigError(f"matchers.relational: the index has no {name!r} set (features {cols})")
        idx = index.sets[name]
        local = [c - sl.start for c in cols]
        if mode == "exact" and len(local) != idx.n_features:
            raise ConfigError(
                f"mode 'exact' compares whole feature sets; select all of {name!r} or use mode 'adaptive'"
            )
        seg = segment(bits, cols)
        # re-express the segment codes in the set's own bit positions
        values = np.zeros(len(seg), np.int64)
        for i, b in enumerate(local):
            values |= ((seg.code >> i) & 1) << b
        mask = sum(1 << b for b in local)
        member = subset_member(values, mask, idx.n_features)
        qlev = np.stack([seg.start, seg.end], axis=1)
        allowed = None if mismatch_positions is None else np.isin(np.arange(len(seg)), mismatch_positions)
        levels, bad = search_set(idx, member, mode, mismatches, allowed, mask)
        dlen = levels[:, :, 1] - levels[:, :, 0]
        qlen = qlev[:, 1] - qlev[:, 0]
        cost = np.abs(dlen - qlen[None, :]).sum(axis=1) / max(int(qlen.sum()), 1)
        clip = np.searchsorted(idx.clip_offsets, levels[:, 0, 0], side="right") - 1
        h = Hits(
            clip.astype(np.int64),
            levels[:, 0, 0],
            levels[:, -1, 1],
            cost.astype(np.float64),
            levels,
            qlev,
            name,
            len(seg),
            {"mismatches": bad},
        )
        parts.append(h)
    if not parts:
        raise ConfigError("matchers.relational: a query needs at least one feature")
    out = parts[0]
    for other in parts[1:]:
        out = combine(out, other, min_overlap)
    return out


def combine(a: Hits, b: Hits, min_overlap: float = 0.5) -> Hits:
    """Hits of two indexes that co-occur: same clip, spans overlapping by ``min_overlap``
    of the shorter span. The result spans the union; its cost is the mean; per-level
    correspondences of the part with more levels are kept for refinement."""
    parts_a: list[np.ndarray] = []
    parts_b: list[np.ndarray] = []
    for c in np.intersect1d(a.clip, b.clip):
        xa, xb = np.flatnonzero(a.clip == c), np.flatnonzero(b.clip == c)
        ov = np.minimum(a.end[xa, None], b.end[None, xb]) - np.maximum(a.start[xa, None], b.start[None, xb])
        shorter = np.minimum((a.end - a.start)[xa, None], (b.end - b.start)[None, xb])
        r, s = np.nonzero(ov >= np.maximum(min_overlap * shorter, 1))
        parts_a.append(xa[r])
        parts_b.append(xb[s])
    ia = np.concatenate(parts_a) if parts_a else np.zeros(0, np.int64)
    ib = np.concatenate(parts_b) if parts_b else np.zeros(0, np.int64)
    keep, kidx = (a, ia) if a.n_levels >= b.n_levels else (b, ib)
    return Hits(
        a.clip[ia],
        np.minimum(a.start[ia], b.start[ib]),
        np.maximum(a.end[ia], b.end[ib]),
        0.5 * (a.cost[ia] + b.cost[ib]),
        None if keep.levels is None else keep.levels[kidx],
        keep.query_levels,
        f"{a.sets}+{b.sets}",
        keep.n_levels,
        {
            "mismatches": a.extra.get("mismatches", np.zeros(len(a), np.int64))[ia]
            + b.extra.get("mismatches", np.zeros(len(b), np.int64))[ib]
        },
    )


def scene_query(
    index: InvertedIndex, progressions: list[list[dict[str, int]]], overlaps: Sequence[tuple[int, ...]] = ()
) -> Hits:
    """Geometric scene description (§6.3): progressions combined under co-occurrence.

    Each progression is a list of constellations ``{feature: 0 or 1}`` over features of one
    set (a feature left out of a step is unspecified, "*"; steps whose alternatives
    intersect are merged, §5.2); an overlap ``(a, i, b, j)`` requires step ``i`` of
    progression ``a`` to overlap in time with step ``j`` of ``b``.
    """
    per: list[Hits] = []
    for p, prog in enumerate(progressions):
        cols = [[feature_column(k) for k in step] for step in prog]
        sets = {feature_set_of(c) for step in cols for c in step}
        if len(sets) != 1:
            raise ConfigError(
                f"scene progression {p} must use features of exactly one set, got {sorted(sets) or 'none'}; "
                "split it into progressions linked by overlaps"
            )
        name = sets.pop()
        idx = index.sets[name]
        base = SET_SLICES[name].start
        member = np.ones((len(prog), 1 << idx.n_features), bool)
        for row, (step, scols) in enumerate(zip(prog, cols, strict=True)):
            for (_, v), c in zip(step.items(), scols, strict=True):
                member[row] &= subset_member(np.array([int(v) << (c - base)]), 1 << (c - base), idx.n_features)[0]
        if len(coarsen_fuzzy(member)) != len(member):
            raise ConfigError(f"scene progression {p}: adjacent steps must differ in a specified feature")
        levels, _ = search_set(idx, member, "adaptive")
        clip = np.searchsorted(idx.clip_offsets, levels[:, 0, 0], side="right") - 1
        per.append(
            Hits(
                clip.astype(np.int64),
                levels[:, 0, 0],
                levels[:, -1, 1],
                np.zeros(len(levels)),
                levels,
                None,
                name,
                len(member),
            )
        )
    if not per:
        raise ConfigError("a scene description needs at least one progression")
    # join progressions one by one; combos[k] holds hit indices into per[k]
    combos = [np.arange(len(per[0]))]
    for b in range(1, len(per)):
        cons = [(a, i, j) for a, i, bb, j in overlaps if bb == b and a < b] + [
            (bb, j, i) for bb, j, a, i in overlaps if a == b and bb < b
        ]
        new_a, new_b = [], []
        hb = per[b]
        for c in np.unique(per[0].clip[combos[0]]):
            ra = np.flatnonzero(per[0].clip[combos[0]] == c)
            rb = np.flatnonzero(hb.clip == c)
            ok = np.ones((len(ra), len(rb)), bool)
            for a, i, j in cons:
                la_all, lb_all = per[a].levels, hb.levels
                assert la_all is not None and lb_all is not None  # scene hits carry their levels
                la = la_all[combos[a][ra], i]
                lb = lb_all[rb, j]
                ok &= np.minimum(la[:, None, 1], lb[None, :, 1]) > np.maximum(la[:, None, 0], lb[None, :, 0])
            r, q = np.nonzero(ok)
            new_a.append(ra[r])
            new_b.append(rb[q])
        sel = np.concatenate(new_a) if new_a else np.zeros(0, np.int64)
        combos = [x[sel] for x in combos] + [np.concatenate(new_b) if new_b else np.zeros(0, np.int64)]
    start = np.min([per[k].start[combos[k]] for k in range(len(per))], axis=0)
    end = np.max([per[k].end[combos[k]] for k in range(len(per))], axis=0)
    return Hits(
        per[0].clip[combos[0]],
        start,
        end,
        np.zeros(len(start)),
        sets="+".join(h.sets for h in per),
        n_levels=sum(h.n_levels for h in per),
    )


__all__ = ["Hits", "Mode", "coarsen_fuzzy", "combine", "example_query", "scene_query", "search_set", "subset_member"]
