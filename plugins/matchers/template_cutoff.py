"""The cut-off of ``matchers.template``: which hits the matcher reports.

Two rules (``cutoff`` of the step):

``threshold``
    A hit is a local cost minimum below the template's calibrated threshold
    (:func:`.template_model.calibrate_threshold`: the best-F1 cut between the left-out
    actors' example costs and the other classes' training clips). Measured on the HDM05
    cuts (docs/templates.md) this carries the ranking's separation over for 5 of 11
    classes only: thresholds learned from templates of fewer actors do not transfer to
    the final template, and one near negative per class already breaks P >= 0.8.
``rivals`` (default)
    The templates of all classes compete, as in Müller & Röder's classification: a hit of
    template ``c`` (key-feature cost below the *acceptance bound*, :func:`acceptance_bound`)
    is kept when ``c``'s all-feature cost on the stretch is at most ``rho`` times the least
    all-feature cost of every other template there (:func:`rival_mask`). All-feature costs
    are comparable between templates (the key features differ per class; classification on
    all 31 features is 0.97 accurate against 0.92 on key features). ``rho = 1`` (plain
    competition) was also the value chosen inside the training actors of every fold.

The acceptance bound only guards against motions of no known class (every HDM05 cut is of
one), so it is loose: the larger of the F1 threshold and ``(1 + guard)`` times the largest
leave-one-actor-out example cost.
"""
from __future__ import annotations

import numpy as np

from .template_model import MotionTemplate


def acceptance_bound(t: MotionTemplate, guard: float = 1.0) -> float:
    """Key-feature cost bound of the ``rivals`` cut-off (module doc)."""
    c = np.asarray(t.example_costs, float)
    c = c[np.isfinite(c)]
    loo = (1 + guard) * float(c.max()) if len(c) else 0.0
    return float(max(t.threshold, loo))


def _all_columns(t: MotionTemplate) -> MotionTemplate:
    return MotionTemplate(t.label, t.mean, np.arange(t.mean.shape[1]), t.delta, t.threshold, t.n_examples, t.example_costs)


def end_windows(start: np.ndarray, end: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per hit ``[s, e)`` the end frames compared with the rivals: ``[e - 1 - h, e + h)``
    with ``h = (e - s) // 2``, inside the hit's clip."""
    s, e = np.asarray(start, np.int64), np.asarray(end, np.int64)
    clip = np.searchsorted(offsets, s, side="right") - 1
    half = (e - s) // 2
    return np.maximum(e - 1 - half, offsets[clip]), np.minimum(e + half, offsets[clip + 1])


def window_min_costs(t: MotionTemplate, codes: np.ndarray, offsets: np.ndarray, lo: np.ndarray,
                     hi: np.ndarray) -> np.ndarray:
    """Least all-feature cost of template ``t`` over paths ending in each window
    ``[lo_i, hi_i)`` (windows inside one clip), shape (n,). Subsequence DTW runs only on the
    windows widened by the longest path (``2K - 1`` frames) to the left, merged."""
    from ._template_kernels import sdtw_cost, window_minima

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
    cost = np.full(len(codes), np.inf)
    sdtw_cost(np.ascontiguousarray(codes, np.int64), np.ascontiguousarray(use.table()), r_lo, r_hi, cost, np.inf)
    return window_minima(cost, np.ascontiguousarray(lo, np.int64), np.ascontiguousarray(hi, np.int64))


def rival_mask(templates: list[MotionTemplate], which: int, start: np.ndarray, end: np.ndarray, codes: np.ndarray,
               offsets: np.ndarray, rho: float = 1.0) -> np.ndarray:
    """Which hits ``[start, end)`` (global frames) of ``templates[which]`` no other template
    beats: own least all-feature cost over :func:`end_windows` <= ``rho`` x the others' least.

    Returns a boolean mask (n_hits,)."""
    if len(templates) < 2 or not len(start):
        return np.ones(len(start), bool)
    lo, hi = end_windows(start, end, offsets)
    own = window_min_costs(templates[which], codes, offsets, lo, hi)
    other = np.full(len(start), np.inf)
    clip_end = offsets[np.searchsorted(offsets, np.asarray(start), side="right")]
    for i, t in enumerate(templates):
        if i != which:  # a rival path covering the stretch may end up to its own length later
            other = np.minimum(other, window_min_costs(t, codes, offsets, lo, np.minimum(hi + t.n_frames, clip_end)))
    return own <= rho * other


__all__ = ["acceptance_bound", "end_windows", "rival_mask", "window_min_costs"]
