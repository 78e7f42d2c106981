"""The movement digression map (MDM) of Aristidou et al. 2018: the analysis of ``cleaners.mdm``.

Texture at 24 fps (§3.1, §5), source words of N frames every step against target words of M
at every context frame per joint group (§3.2), the KNN (:mod:`.knn`, §3.3), the
mean-motion-texture T̄ (chordal mean of the KNN words covering a cell), ``M = |T - T̄|``
over its row mean (floored at :data:`MEAN_FLOOR`) and ``MDM = 1 - exp(-M^2)`` (§3.4).
Contexts: ``None`` (the clip itself), a Motion, a list of Motions or a MotionDatabase.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from mocapflow.framework import quaternions as quat
from mocapflow.framework.errors import DataError
from mocapflow.framework.motion import Motion

from .knn import ContextTextures, WordNeighbours, knn_search
from .motion_words import Texture, context_motions, motion_texture, resolve_groups, source_word_starts


class MDMAnalysis(Protocol):
    """What the analysis reads of the cleaner's parameters (``cleaner.MDMParams``; declared
    here, so the analysis does not import the cleaner that calls it)."""

    @property
    def fps(self) -> float: ...
    @property
    def joints(self) -> tuple[str, ...]: ...
    @property
    def source_length(self) -> int: ...
    @property
    def source_step(self) -> int: ...
    @property
    def target_length(self) -> int: ...
    @property
    def k(self) -> int: ...
    @property
    def slope_run(self) -> int: ...
    @property
    def exclusion(self) -> int | None: ...
    @property
    def include_self(self) -> bool: ...
    def groups_tuple(self) -> tuple[tuple[str, tuple[str, ...], int], ...]: ...


__all__ = ["DigressionResult", "context_motions", "digression_map"]

#: Floor of the row mean of ``M`` (radians): a joint never rotated is not blown up to 1.
MEAN_FLOOR = 0.01


@dataclass
class DigressionResult:
    """Everything :func:`digression_map` computed for one clip, (T, m) at the analysis rate:
    ``mean_texture`` T̄ (T, m, 4) (the texture where no KNN word covers a cell),
    ``difference`` (angle T to T̄, radians), ``mdm`` in [0, 1], ``neighbours`` (empty when
    the clip is shorter than one word), ``spread`` (:func:`knn_spread`)."""

    texture: Texture
    mean_texture: np.ndarray
    difference: np.ndarray
    mdm: np.ndarray
    neighbours: list[WordNeighbours] = field(default_factory=list)
    seconds: float = 0.0
    n_dtw: int = 0
    spread: np.ndarray | None = None

    @property
    def joints(self) -> tuple[str, ...]:
        return self.texture.joints


def accumulate(neigh: WordNeighbours, n_frames: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Sum of ``q q^T`` of every KNN word over the cells it covers (T, m, 4, 4), and how
    many (T, m) int64."""
    m = neigh.warped.shape[4]
    outer = np.zeros((n_frames, m, 4, 4))
    count = np.zeros((n_frames, m), np.int64)
    frames = neigh.starts[:, None] + np.arange(n)[None, :]  # (S, N)
    for g in range(neigh.groups.n_groups):
        valid = (neigh.target[g] >= 0).astype(float)  # (S, K)
        jm = neigh.groups.mask[g]
        w = neigh.warped[g][..., jm, :]  # (S, K, N, mg, 4)
        o = np.einsum("sk,skija,skijb->sijab", valid, w, w)
        c = valid.sum(1).astype(np.int64)
        cols = np.flatnonzero(jm)[None, :]
        for i in range(n):
            # word starts are distinct, so one word offset never hits a frame twice
            rows = frames[:, i][:, None]
            outer[rows, cols] += o[:, i]
            count[rows, cols] += c[:, None]
    return outer, count


def knn_spread(outer: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Scatter of the KNN samples about their chordal mean per cell, radians (T, m); 0 where
    none. The largest eigenvalue of ``outer`` over ``count`` is the mean ``cos^2(theta/2)``,
    so ``2 arcsin(sqrt(1 - lambda / n))`` is the RMS-style angle of the samples about T̄."""
    out = np.zeros(count.shape)
    covered = count > 0
    if covered.any():
        lam = np.linalg.eigvalsh(outer[covered])[..., -1] / count[covered]
        out[covered] = 2.0 * np.arcsin(np.sqrt(np.clip(1.0 - lam, 0.0, 1.0)))
    return out


def digression_from_outer(
    q: np.ndarray, outer: np.ndarray, count: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """T̄, the geodesic difference, the KNN spread and the MDM from accumulated outer products (§3.4)."""
    mean_q = q.copy()
    covered = count > 0
    if covered.any():
        mean_q[covered] = quat.mean_of_outer(outer[covered])
    diff = np.where(covered, quat.geodesic_angle(q, mean_q), 0.0)
    spread = knn_spread(outer, count)
    scale = np.maximum(diff.mean(axis=0, keepdims=True), MEAN_FLOOR)
    m = np.where(scale > 0, diff / np.where(scale > 0, scale, 1.0), 0.0)
    return mean_q, diff, spread, 1.0 - np.exp(-(m**2))


def digression_map(motion: Motion, context: Any, p: MDMAnalysis) -> DigressionResult:
    """The MDM of ``motion`` against ``context`` (module doc) with the cleaner's parameters."""
    t0 = time.perf_counter()
    clips = context_motions(motion, context, p.include_self)
    joints = tuple(j for j in p.joints if all(j in c.skeleton.canonical for c in clips))
    if not joints:
        raise DataError(f"motion {motion.name!r}: no texture joint is mapped by every context clip")
    tex = motion_texture(motion, joints, p.fps)
    ctx_tex = [tex.q if c is motion else motion_texture(c, joints, p.fps).q for c in clips]
    self_clip = 0 if p.include_self else -1
    groups = resolve_groups(joints, p.groups_tuple())
    n = p.source_length
    starts = source_word_starts(tex.n_frames, n, p.source_step)
    full = ContextTextures.from_arrays(ctx_tex, [c.name for c in clips])
    searches: list[WordNeighbours] = []
    if len(starts) == 0:
        outer = np.zeros(tex.q.shape[:2] + (4, 4))
        count = np.zeros(tex.q.shape[:2], np.int64)
    else:
        searches.append(
            knn_search(
                tex.q,
                full,
                groups,
                self_clip=self_clip,
                word_starts=starts,
                source_length=n,
                target_length=p.target_length,
                k=p.k,
                slope_run=p.slope_run,
                radius=p.exclusion,
            )
        )
        outer, count = accumulate(searches[0], tex.n_frames, n)
    mean_q, diff, spread, mdm = digression_from_outer(tex.q, outer, count)
    return DigressionResult(
        tex, mean_q, diff, mdm, searches, time.perf_counter() - t0, sum(s.n_dtw for s in searches), spread
    )
