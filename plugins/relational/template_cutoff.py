"""The cut-off of ``matchers.template``: which hits the matcher reports.

The templates of all classes compete, as in Müller & Röder's classification: a hit of
template ``c`` (key-feature cost below the *acceptance bound*, :func:`acceptance_bound`) is
kept when ``c``'s all-feature cost on the stretch is at most ``rho`` times the least
all-feature cost of every other template there (:func:`rival_mask`). All-feature costs are
comparable between templates (the key features differ per class). ``rho = 1`` (plain
competition) was also the value chosen inside the training actors of every fold. A plain
calibrated threshold lost (5 of 11 HDM05 classes against 9: docs/templates.md).

For many queries on one database the rivals' costs are the same every time:
:class:`RivalTable` computes every template's all-feature end costs once (like an index)
and answers the rival check by lookups; :func:`rival_mask` scans only the hits' windows
(one query, no table).

A rival rejects only a stretch its own path can span: the search's steps compress a
template at most 2x, so a rival of ``K`` frames spans at most ``2K`` (:data:`COVER`); a
short template matching a part of a longer motion (a kick's leg lift inside a lie-down)
cannot silence the longer class there. Measured leave-one-actor-out on the HDM05 cuts: 11
of 11 classes against 9 with every rival (docs/templates.md).

The acceptance bound only guards against motions of no known class (every HDM05 cut is of
one), so it is loose: the larger of the F1 threshold and ``(1 + guard)`` times the largest
leave-one-actor-out example cost.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .template_model import MotionTemplate

#: A rival of ``K`` frames may reject a hit spanning at most ``K / COVER`` frames (the
#: search's steps compress a template at most 2x).
COVER = 0.5


def acceptance_bound(t: MotionTemplate, guard: float = 1.0) -> float:
    """Key-feature cost bound of the ``rivals`` cut-off (module doc)."""
    c = np.asarray(t.example_costs, float)
    c = c[np.isfinite(c)]
    loo = (1 + guard) * float(c.max()) if len(c) else 0.0
    return float(max(t.threshold, loo))


def _all_columns(t: MotionTemplate) -> MotionTemplate:
    return MotionTemplate(
        t.label, t.mean, np.arange(t.mean.shape[1]), t.delta, t.threshold, t.n_examples, t.example_costs
    )


def end_windows(start: np.ndarray, end: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per hit ``[s, e)`` the end frames compared with the rivals: ``[e - 1 - h, e + h)``
    with ``h = (e - s) // 2``, inside the hit's clip."""
    s, e = np.asarray(start, np.int64), np.asarray(end, np.int64)
    clip = np.searchsorted(offsets, s, side="right") - 1
    half = (e - s) // 2
    return np.maximum(e - 1 - half, offsets[clip]), np.minimum(e + half, offsets[clip + 1])


def window_min_costs(
    t: MotionTemplate,
    codes: np.ndarray,
    offsets: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    bound: np.ndarray | float = np.inf,
) -> np.ndarray:
    """Least all-feature cost of template ``t`` over paths ending in each window
    ``[lo_i, hi_i)`` (windows inside one clip), shape (n,); exact where ``<= bound`` (per
    window, or one value), inf or exact above (early abandoning). Subsequence DTW runs only
    on the windows widened by the longest path (``2K - 1`` frames) to the left, merged (a
    merged range abandons above the largest bound of its windows)."""
    from ._hit_kernels import window_minima
    from ._template_kernels import sdtw_cost

    n = len(lo)
    if not n:
        return np.zeros(0)
    use = _all_columns(t)
    clip = np.searchsorted(offsets, lo, side="right") - 1
    rlo = np.maximum(lo - 2 * t.n_frames + 1, offsets[clip])
    order = np.lexsort((rlo, clip))
    a, b, cl = rlo[order], hi[order], clip[order]
    run_hi = np.maximum.accumulate(b)  # within one clip ranges are sorted by start
    new = np.r_[True, (a[1:] > run_hi[:-1]) | (cl[1:] != cl[:-1])]
    first = np.flatnonzero(new)
    r_lo = np.ascontiguousarray(a[first])
    r_hi = np.ascontiguousarray(np.maximum.reduceat(b, first))
    bounds = np.maximum.reduceat(np.broadcast_to(np.asarray(bound, np.float64), (n,))[order], first)
    cost = np.full(len(codes), np.inf)
    sdtw_cost(
        np.ascontiguousarray(codes, np.int64),
        np.ascontiguousarray(use.table()),
        r_lo,
        r_hi,
        cost,
        np.ascontiguousarray(bounds, np.float64),
    )
    return window_minima(cost, np.ascontiguousarray(lo, np.int64), np.ascontiguousarray(hi, np.int64))


def rival_mask(
    templates: list[MotionTemplate],
    which: int,
    start: np.ndarray,
    end: np.ndarray,
    codes: np.ndarray,
    offsets: np.ndarray,
    rho: float = 1.0,
) -> np.ndarray:
    """Which hits ``[start, end)`` (global frames) of ``templates[which]`` no other template
    beats: own least all-feature cost over paths ending in :func:`end_windows` <= ``rho`` x
    the least cost of every other template over paths ending there or up to ``K - 1``
    frames later (``K`` the rival's length: a longer rival path covering the stretch). Only
    rivals that can span the hit compete (``K >= COVER x`` its frames).

    Returns a boolean mask (n_hits,)."""
    if len(templates) < 2 or not len(start):
        return np.ones(len(start), bool)
    lo, hi = end_windows(start, end, offsets)
    own = window_min_costs(templates[which], codes, offsets, lo, hi)
    other = np.full(len(start), np.inf)
    clip_end = offsets[np.searchsorted(offsets, np.asarray(start), side="right")]
    # a rival matters only below own / rho: its scan of each window abandons paths above that
    bound = own / rho
    span = np.asarray(end) - np.asarray(start)
    for i, t in enumerate(templates):
        if i != which:  # a rival path covering the stretch may end up to its own length later
            can = t.n_frames >= COVER * span
            if can.any():
                c = window_min_costs(t, codes, offsets, lo, np.minimum(hi + t.n_frames - 1, clip_end), bound)
                other = np.minimum(other, np.where(can, c, np.inf))
    return own <= rho * other


@dataclass
class RivalTable:
    """Every template's all-feature end costs over one database, for the rival check of
    many queries (module doc): ``own`` (T, N) float32, the end cost of each template at
    each frame (inf where no path ends); ``lengths`` (T,) the templates' frames."""

    own: np.ndarray
    lengths: np.ndarray

    @classmethod
    def build(cls, templates: list[MotionTemplate], codes: np.ndarray, offsets: np.ndarray) -> RivalTable:
        from .template_model import template_costs

        ranges = np.stack([offsets[:-1], offsets[1:]], axis=1)
        own = np.empty((len(templates), len(codes)), np.float32)
        for i, t in enumerate(templates):
            own[i] = template_costs(codes, _all_columns(t).table(), ranges)[0]
        return cls(own, np.array([t.n_frames for t in templates], np.int64))

    def mask(self, which: int, start: np.ndarray, end: np.ndarray, offsets: np.ndarray, rho: float = 1.0) -> np.ndarray:
        """:func:`rival_mask` by lookups: per rival that can span the hit, its least end cost
        over the window extended by its length (a rival path covering the stretch)."""
        from ._hit_kernels import window_minima

        if len(self.own) < 2 or not len(start):
            return np.ones(len(start), bool)
        lo, hi = end_windows(start, end, offsets)
        lo, hi = np.ascontiguousarray(lo, np.int64), np.ascontiguousarray(hi, np.int64)
        # only the hits' windows are read (no whole-database temporaries: the check is lookups)
        own = window_minima(self.own[which], lo, hi)
        clip_end = offsets[np.searchsorted(offsets, np.asarray(start), side="right")]
        span = np.asarray(end) - np.asarray(start)
        other = np.full(len(lo), np.inf)
        for i, k in enumerate(self.lengths):
            can = np.flatnonzero(k >= COVER * span) if i != which else np.zeros(0, np.int64)
            if len(can):
                r_hi = np.ascontiguousarray(np.minimum(hi[can] + k - 1, clip_end[can]), np.int64)
                other[can] = np.minimum(other[can], window_minima(self.own[i], np.ascontiguousarray(lo[can]), r_hi))
        return own <= rho * other


__all__ = ["COVER", "RivalTable", "acceptance_bound", "end_windows", "rival_mask", "window_min_costs"]
