"""The null of a take, measured on the context words most like it (calibrated cleaner).

Which context motion calibrates a take is decided by similarity, not by clip length: the
take's own KNN words (:mod:`..paper.knn`) point into the context; the frames they cover,
grown by :data:`.constants.SPAN_PAD` frames and cut into spans, are ranked by how many KNN
words cover them per frame, and the densest spans up to ``frames`` analysis frames are
analysed against the rest of the context (their own clip left out) exactly as the take is.
The detectors' evidence on those spans is the take's null
(:func:`.null.context_null`). The null shipped with the package is used instead, and the
reason is returned, when the context holds no other clip, when under
:data:`.constants.MIN_SIMILAR` of the take's KNN words lie in it (unlike motion), or when the
spans hold under :data:`.constants.NULL_MIN_FRAMES` frames (a small context).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from .constants import MIN_SIMILAR, NULL_MIN_FRAMES, SPAN_PAD
from .null import Null, context_null, shipped_null

if TYPE_CHECKING:  # pragma: no cover
    from mocapflow.framework.motion import Motion


def _cover(res: Any, lengths: np.ndarray, target_length: int) -> tuple[np.ndarray, float]:
    """KNN-word coverage count per frame of the concatenated context (C,) (clip 0 the take,
    of length 0 when it was not searched), and the share of the take's KNN words that lie
    outside the take."""
    total = int(lengths.sum())
    cover = np.zeros(total + target_length, np.int64)
    if not res.neighbours:
        return cover[:total], 0.0
    tg = res.neighbours[0].target.ravel()
    tg = tg[tg >= 0]
    if len(tg) == 0:
        return cover[:total], 0.0
    np.add.at(cover, tg, 1)
    cover = np.convolve(cover, np.ones(target_length, np.int64))[: total + target_length]
    share = float((tg >= lengths[0]).mean())
    return cover[:total], share


def similar_spans(
    res: Any, others: Sequence[Any], fps: float, frames: int, target_length: int = 20, self_first: bool = True
) -> tuple[list[tuple[int, int, int, np.ndarray]], float]:
    """(clip index in ``others``, first, end analysis frame, covered mask) of the densest
    KNN-covered spans up to ``frames`` analysis frames, and the share of the take's KNN words
    in ``others``. ``res`` is the take's analysis, with itself first in its context when
    ``self_first``."""
    from mocapflow.framework.normalize import resample

    lengths = np.array(
        [res.texture.n_frames if self_first else 0] + [resample(c, fps).n_frames for c in others], np.int64
    )
    cover, share = _cover(res, lengths, target_length)
    offs = np.concatenate([[0], np.cumsum(lengths)])
    cands = []
    for i in range(len(others)):
        c = cover[offs[i + 1] : offs[i + 2]]
        hit = c > 0
        grown = hit.copy()
        for o in range(1, SPAN_PAD + 1):
            grown[o:] |= hit[:-o]
            grown[:-o] |= hit[o:]
        d = np.diff(np.concatenate([[0], grown.astype(np.int8), [0]]))
        for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True):
            if b - a >= 3 * target_length // 2:
                cands.append((-float(c[a:b].sum()) / (b - a), i, int(a), int(b), hit[a:b]))
    chosen, total = [], 0
    for _, ci, ca, cb, h in sorted(cands, key=lambda x: x[:4]):
        if total >= frames:
            break
        chosen.append((int(ci), int(ca), int(cb), h))
        total += int(cb - ca)
    return chosen, share


def calibrate(
    res: Any,
    take: Motion,
    others: Sequence[Any],
    analyse: Callable[..., Any],
    fps: float,
    *,
    frames: int = 600,
    self_first: bool = True,
) -> Null:
    """The take's null (module doc) from its analysis ``res`` (the take first in its context
    when ``self_first``); ``analyse(motion, context)`` is the cleaner's analysis with the clip
    itself included."""
    from .detectors import evidence

    joints = res.joints
    if not others:
        return shipped_null(joints)
    spans, share = similar_spans(res, others, fps, frames, self_first=self_first)
    if share < MIN_SIMILAR:
        return shipped_null(
            joints, f"context unlike the take ({share:.0%} of its KNN words in the context, < {MIN_SIMILAR:.0%})"
        )
    evs, masks, names = [], [], []
    for i, a, b, hit in spans:
        clip = others[i]
        r = clip.fps / fps
        crop = clip.slice(int(a * r), min(clip.n_frames, int(np.ceil(b * r)) + 1)).with_arrays(
            name=f"{clip.name}[{a}:{b}]"
        )
        rest = [c for k, c in enumerate(others) if k != i]
        out = analyse(crop, rest)
        cols = [list(out.joints).index(j) for j in joints]
        sp = None if out.spread is None else out.spread[:, cols]
        ev = evidence(out.texture.q[:, cols], out.mean_texture[:, cols], sp, joints)
        n = min(len(ev), len(hit))
        mask = np.zeros(len(ev), bool)
        mask[:n] = True
        mask[:2] = mask[-2:] = False  # the span's own ends have no neighbours on one side
        evs.append(ev)
        masks.append(mask)
        names.append(crop.name)
    n_frames = int(sum(m.sum() for m in masks))
    if n_frames < NULL_MIN_FRAMES:
        return shipped_null(
            joints,
            f"context too small ({n_frames / fps:.1f} s of words like the take, < {NULL_MIN_FRAMES / fps:.0f} s)",
        )
    return context_null(evs, masks, joints, names)
