"""Coarse-rate search of ``matchers.template``: the DTW on a temporally decimated feature sequence.

The subsequence DTW costs ``K x N`` cells (template frames x database frames); keeping every
``s``-th frame of both the template and each database clip costs ``(K / s) x (N / s)``, about
``s**2`` times fewer. Müller & Röder's templates are also computed at a reduced feature rate
(their 2006 paper is not in ``../shared/papers``; the 2005 paper's features are evaluated per
frame at the capture rate, 120 Hz, and say nothing about templates), so the rate here is our
choice, measured in docs/templates.md.

Only the *search* runs at the coarse rate: the template's rows ``0, s, 2s, ...`` against the
database frames ``offsets[i], offsets[i] + s, ...`` of every clip (the kernel's admissible
per-clip bound on the coarse frames) and the same acceptance bound (costs are mean local costs in [0, 1] at either rate). The hits are mapped
back to full-rate frames and the rival check of the ``rivals`` cut-off runs at the full rate
on them, so which class wins a stretch is decided as before.

``step="auto"`` (default of the step): per template ``s = clip(K // 7, 1, 4)``: at least 7 coarse rows, at most a quarter of the rate
(hop, 22 frames at 30 Hz: s = 3; every other HDM05 template: 4). Measured
leave-one-actor-out, a uniform step of 6 (5 Hz; rotate's 32 frames become 6 rows) loses two
classes, steps 2-4 none; a class's list depends only on its own step (the rival check runs
at the full rate), so ``auto`` inherits that.
"""

from __future__ import annotations

from typing import cast

import numpy as np

from .template_model import MotionTemplate


def coarse_layout(offsets: np.ndarray, step: int) -> tuple[np.ndarray, np.ndarray]:
    """Every ``step``-th frame of each clip (from its first frame): the full-rate frame (M,)
    int64 of each coarse frame, ascending, and the clip offsets (n_clips + 1,) among them."""
    off = np.asarray(offsets, np.int64)
    lens = np.diff(off)
    n = (lens + step - 1) // step
    coarse_off = np.concatenate([[0], np.cumsum(n)]).astype(np.int64)
    clip = np.repeat(np.arange(len(lens)), n)
    frames = off[:-1][clip] + step * (np.arange(int(coarse_off[-1])) - coarse_off[:-1][clip])
    return frames.astype(np.int64), coarse_off


def coarse_template(t: MotionTemplate, step: int) -> MotionTemplate:
    """The template's rows ``0, step, 2 step, ...`` (at least one row)."""
    if step <= 1:
        return t
    key = (step, t.columns.tobytes(), t.delta, t.mean.shape)
    cached = t._coarse
    if cached is None or cached[0] != key:  # kept on the template: its lookup table is cached on it in turn
        cached = (
            key,
            MotionTemplate(
                t.label,
                np.ascontiguousarray(t.mean[::step]),
                t.columns,
                t.delta,
                t.threshold,
                t.n_examples,
                t.example_costs,
            ),
        )
        t._coarse = cached
    return cast("MotionTemplate", cached[1])


#: ``step="auto"``: template frames per coarse template frame, and the largest step.
COARSE_FRAMES, MAX_STEP = 7, 4


def template_step(t: MotionTemplate, step: int | str) -> int:
    """The decimation step for one template: ``step`` itself, or for ``"auto"``
    ``clip(K // COARSE_FRAMES, 1, MAX_STEP)``."""
    if step == "auto":
        return int(np.clip(t.n_frames // COARSE_FRAMES, 1, MAX_STEP))
    return max(int(step), 1)


class CoarseCodes:
    """Frame codes of one database at each decimation step, built on first use (cheap: one gather)."""

    def __init__(self, codes: np.ndarray, offsets: np.ndarray):
        self.codes, self.offsets = codes, np.asarray(offsets, np.int64)
        self._by_step: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def get(self, step: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(codes, coarse_offsets, frames)`` at ``step``."""
        if step not in self._by_step:
            if step <= 1:
                return self.codes, self.offsets, np.arange(len(self.codes), dtype=np.int64)
            frames, off = coarse_layout(self.offsets, step)
            self._by_step[step] = (np.ascontiguousarray(self.codes[frames]), off, frames)
        return self._by_step[step]


def coarse_search(
    t: MotionTemplate, coarse: CoarseCodes, ranges: np.ndarray | None, bound: float, min_gap: float, step: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hits ``(start, end exclusive, cost)`` in full-rate frames of template ``t`` (already on
    the columns to use) searched at ``step`` over the full-rate ``ranges`` (R, 2); None: every
    clip (the kernel's admissible per-clip bound, ``_template_kernels.sdtw_cost``)."""
    from .template_model import search_costs

    codes, coff, frames = coarse.get(step)
    ct = coarse_template(t, step)
    if ranges is None:  # every clip (the kernel skips a clip whose lower bound exceeds the bound)
        r = np.stack([coff[:-1], coff[1:]], axis=1)
    else:
        r = np.asarray(ranges, np.int64).reshape(-1, 2)
        if step > 1:  # full-rate [lo, hi) -> the coarse frames inside it
            r = np.stack([np.searchsorted(frames, r[:, 0]), np.searchsorted(frames, r[:, 1])], axis=1)
            r = r[r[:, 1] > r[:, 0]]
    s, e, c, _ = search_costs(codes, ct.table(), r, bound, min_gap)
    if step > 1:
        s, e = frames[s], frames[e - 1] + 1
    return s, e, c


__all__ = ["CoarseCodes", "coarse_layout", "coarse_search", "coarse_template", "template_step"]
