"""The movement digression map (MDM) cleaner of Aristidou et al. 2018 (``cleaners.mdm``).

Pipeline of one clip (paper section in brackets):

1. resample to 24 fps, drop the root translation, align the facing direction, take the
   texture of the 24 most informative joints (§3.1, §5 Implementation);
2. source words of 15 frames every 5 frames, target words of 20 frames at every context
   frame, compared per joint group by constrained DTW over eq. 1 (§3.2, Appendix);
3. KNN = the K = 5 smallest local minima of each word's distance function, away from the
   word itself (§3.3), found exactly by :mod:`.knn`;
4. mean-motion-texture T̄ (chordal quaternion mean of every KNN word covering a cell),
   ``M = |T - T̄|`` as a geodesic angle, each joint's row divided by a scale, and
   ``MDM = 1 - exp(-M^2)`` (§3.4);
5. cells above 0.5 repaired from the median KNN word, blended by a quadratic
   Savitzky-Golay filter (§4, :mod:`.repair`).

Row normalisation. §3.4 divides "each row of the resulting map M by the mean of that
row"; that is ``normalization="mean"`` (the mean floored at ``mean_floor`` = 0.01 rad so
that numerically-zero rows, e.g. a joint the capture never rotates, are not scaled up to 1
everywhere). Read literally it flags every cell whose difference exceeds 0.83 times its
joint's mean difference, whatever the joint's noise: on clean CMU takes 30-45 % of the
cells far from any error exceed 0.5 (measured), cell precision ~0.03 (docs/cleaning.md).
The default is therefore ``"median"``: the row is divided by ``robust_factor`` (2.5) times
its *median*, a robust estimate of how far a clean cell of that joint typically is from
its KNN mean (errors are a few percent of a row and cannot move the median, while they
inflate the mean), so a cell is flagged when it digresses more than ~2 times its joint's
typical digression. Same analysis, same KNN, only the scale differs; on the evaluation
harness cell precision rises 2-3x on locomotion and dance at a lower recall. ``"spread"``
divides each cell by ``spread_factor`` times the scatter of the KNN samples about T̄ at that
cell (:func:`knn_spread`; where the neighbours disagree, a digression means less): the
most precise on locomotion, but it misses most errors in dance, whose neighbours scatter
widely. ``"texture"`` divides by the joint's mean rotation angle in T (floored at
``min_scale``); ``"none"`` keeps radians.

Modes. ``mode="paper"`` is the paper literally (with ``normalization="mean"``, the
default): cells whose MDM exceeds 0.5 are repaired from the median KNN word and blended
by Savitzky-Golay (:mod:`.repair`). ``mode="calibrated"`` (the default, issue 14) keeps
the same analysis but decides with a detector fitted on the user's clean context
(:mod:`.calibration`: self-supervised, per-joint nulls, cues of :mod:`.cues`, a target
``false_alarm`` rate) and repairs with bounds (:mod:`.bounded_repair`), so an uncorrupted
take is left essentially untouched. Its map value is ``1 - 2^(-e^2)`` of the cell's
evidence ``e`` (0.5 where ``e`` = 1, the decision level).

Contexts (§3.1, §5): ``None`` (the clip itself), a Motion, a list of Motions or a
:class:`~mocapflow.framework.database.MotionDatabase`; the clip is added to its context
unless ``include_self`` is off. ``two_stage`` runs the §5 scheme: the stage-1 groups
against the clip alone, then the other groups against the whole context only around
distinct stage-1 words.
"""
from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from mocapflow.framework import quaternions as quat
from mocapflow.framework.components import Cleaner, Params
from mocapflow.framework.errors import ConfigError, DataError
from mocapflow.framework.motion import Motion

from .knn import ContextTextures, WordNeighbours, knn_search

if TYPE_CHECKING:
    from .decision import CleanResult
from .mdm_params import JointGroup, MDMParams
from .motion_words import Texture, context_motions, motion_texture, resolve_groups, source_word_starts

__all__ = ["DigressionResult", "JointGroup", "MDMCleaner", "MDMParams", "context_motions", "digression_map"]


@dataclass
class DigressionResult:
    """Everything :func:`digression_map` computed for one clip (at the analysis rate).

    Attributes
    ----------
    texture : Texture
    mean_texture : ndarray of shape (T, m, 4)
        T̄; equal to the texture where no KNN word covers a cell.
    difference : ndarray of shape (T, m)
        Geodesic angle between T and T̄, radians (before row normalisation).
    mdm : ndarray of shape (T, m), values in [0, 1]
    neighbours : list of WordNeighbours
        One per search (two with ``two_stage``; the later one wins where it covers).
    seconds : float
    n_dtw : int
    spread : ndarray of shape (T, m)
        Scatter of the KNN samples about T̄ per cell, radians (:func:`knn_spread`).
    """

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
    """Sum of ``q q^T`` of every KNN word over the cells it covers, and how many.

    Returns
    -------
    outer : ndarray of shape (T, m, 4, 4)
    count : ndarray of shape (T, m), int64
    """
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
    """Scatter of the KNN samples around their chordal mean, per cell (radians).

    The largest eigenvalue of ``sum q q^T`` over ``n`` unit quaternions is ``n`` times the
    mean of ``cos^2(theta_i / 2)``, ``theta_i`` the rotation angle from the chordal mean to
    sample ``i``; ``2 arcsin(sqrt(1 - lambda / n))`` is then the RMS-style angle
    (``sqrt(mean sin^2(theta_i / 2))`` mapped back to an angle) of the samples about T̄, in the
    convention of :func:`~mocapflow.framework.quaternions.geodesic_angle`.

    Parameters
    ----------
    outer : ndarray of shape (T, m, 4, 4)
    count : ndarray of shape (T, m)

    Returns
    -------
    ndarray of shape (T, m)
        0 where no sample covers the cell.
    """
    out = np.zeros(count.shape)
    covered = count > 0
    if covered.any():
        lam = np.linalg.eigvalsh(outer[covered])[..., -1] / count[covered]
        out[covered] = 2.0 * np.arcsin(np.sqrt(np.clip(1.0 - lam, 0.0, 1.0)))
    return out


def row_scale(diff: np.ndarray, q: np.ndarray, spread: np.ndarray | None, p: MDMParams) -> np.ndarray:
    """The scale ``M = |T - T̄|`` is divided by (§3.4), broadcastable to (T, m); see
    :class:`MDMParams` ``normalization``."""
    if p.normalization == "mean":
        return np.maximum(diff.mean(axis=0, keepdims=True), p.mean_floor)
    if p.normalization == "texture":
        return np.maximum(quat.geodesic_angle(q, quat.identity(q.shape[:-1])).mean(axis=0, keepdims=True), p.min_scale)
    if p.normalization == "median":
        return p.robust_factor * np.maximum(np.median(diff, axis=0, keepdims=True), p.noise_floor)
    if p.normalization == "spread":
        if spread is None:
            raise DataError("normalization 'spread' needs the KNN spread")
        return p.spread_factor * np.sqrt(spread ** 2 + p.noise_floor ** 2)
    return np.ones((1, diff.shape[1]))


def digression_from_outer(q: np.ndarray, outer: np.ndarray, count: np.ndarray, params: MDMParams | None = None,
                          difference: np.ndarray | None = None, spread: np.ndarray | None = None
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """T̄, the geodesic difference, the KNN spread and the MDM from accumulated outer products (§3.4).

    ``params.normalization`` picks the scale ``M`` is divided by (:func:`row_scale`). Given
    ``difference`` and ``spread`` (T, m), the mean is skipped (``outer`` and ``count`` are
    ignored and T̄ is returned as ``q``): another normalisation of the same analysis.
    """
    p = params or MDMParams()
    mean_q = q.copy()
    if difference is not None:
        diff = difference
    else:
        covered = count > 0
        if covered.any():
            mean_q[covered] = quat.mean_of_outer(outer[covered])
        diff = np.where(covered, quat.geodesic_angle(q, mean_q), 0.0)
        spread = knn_spread(outer, count)
    scale = row_scale(diff, q, spread, p)
    m = np.where(scale > 0, diff / np.where(scale > 0, scale, 1.0), 0.0)
    return mean_q, diff, spread, 1.0 - np.exp(-(m ** 2))


def digression_map(motion: Motion, context: Any = None, params: MDMParams | None = None) -> DigressionResult:
    """The MDM of ``motion`` against ``context`` (see module doc).

    Parameters
    ----------
    motion : Motion
    context : None, Motion, list of Motion or MotionDatabase
    params : MDMParams

    Returns
    -------
    DigressionResult
    """
    p = params or MDMParams()
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
    kw = dict(source_length=n, target_length=p.target_length, k=p.k, slope_run=p.slope_run, radius=p.exclusion,
              method=p.knn_method, warp=p.warp)
    full = ContextTextures.from_arrays(ctx_tex, [c.name for c in clips])
    searches: list[WordNeighbours] = []
    if len(starts) == 0:
        outer = np.zeros(tex.q.shape[:2] + (4, 4))
        count = np.zeros(tex.q.shape[:2], np.int64)
    elif not p.two_stage:
        searches.append(knn_search(tex.q, full, groups, self_clip=self_clip, word_starts=starts, **kw))
        outer, count = accumulate(searches[0], tex.n_frames, n)
    else:
        outer, count = _two_stage(tex, full, groups, starts, p, kw, searches)
    mean_q, diff, spread, mdm = digression_from_outer(tex.q, outer, count, p)
    return DigressionResult(tex, mean_q, diff, mdm, searches, time.perf_counter() - t0, sum(s.n_dtw for s in searches),
                            spread)


def _subset(groups, keep: np.ndarray):
    from .motion_words import JointGroups

    return JointGroups(tuple(n for n, k in zip(groups.names, keep) if k), groups.mask[keep], groups.drop[keep])


def _two_stage(tex: Texture, full: ContextTextures, groups, starts: np.ndarray, p: MDMParams, kw: dict,
               searches: list[WordNeighbours]) -> tuple[np.ndarray, np.ndarray]:
    """§5: stage-1 groups against the clip alone; the other groups against the whole context
    for the words that overlap a cell flagged by stage 1. Stage 2 replaces stage 1 on the
    cells it covers."""
    n = p.source_length
    first = np.isin(groups.names, p.stage1_groups)
    if not first.any():
        raise ConfigError(f"two_stage: none of stage1_groups {p.stage1_groups} is a joint group ({groups.names})")
    local = ContextTextures.from_arrays([tex.q], [full.names[0]])
    s1 = knn_search(tex.q, local, _subset(groups, first), self_clip=0, word_starts=starts, **kw)
    searches.append(s1)
    outer, count = accumulate(s1, tex.n_frames, n)
    mdm1 = digression_from_outer(tex.q, outer, count, p)[3]
    flagged_frames = np.flatnonzero((mdm1 > p.threshold).any(axis=1))
    second = ~first if (~first).any() else first
    distinct = np.array([s for s in starts if np.any((flagged_frames >= s) & (flagged_frames < s + n))], np.int64)
    if len(distinct) == 0:
        return outer, count
    s2 = knn_search(tex.q, full, _subset(groups, second), self_clip=0, word_starts=distinct, **kw)
    searches.append(s2)
    o2, c2 = accumulate(s2, tex.n_frames, n)
    take = c2 > 0
    outer[take] = o2[take]
    count[take] = c2[take]
    return outer, count


class MDMCleaner(Cleaner):
    """Self-similarity cleaning with the movement digression map (Aristidou et al. 2018).

    ``detect`` returns the map at the input clip's frames for every skeleton joint (0 for
    joints outside the texture; > 0.5 = flagged); ``repair`` the cleaned clip and its edits
    table; ``clean`` everything (:class:`CleanResult`).
    """

    name = "mdm"
    version = "3"  # 3: session 7 (merged runs stop at cells a rule left alone; the carry guard; the calibration budget at the analysis rate)
    Params: ClassVar[type[Params]] = MDMParams

    def analyse(self, motion: Motion, context: Any = None) -> DigressionResult:
        """The full analysis at the analysis rate (texture, T̄, MDM, neighbours)."""
        return digression_map(motion, context, self.params)

    def clean(self, motion: Motion, context: Any = None, contacts: Sequence[Any] = ()) -> "CleanResult":
        """Analysis, decision and repair of one clip (see :class:`CleanResult`)."""
        from mocapflow.framework.cleaning import check_take

        from .decision import clean_motion

        check_take(motion, self.key())

        return clean_motion(self, motion, context, contacts)

    def detect(self, motion: Motion, context: Any = None) -> np.ndarray:
        """Digression map at the input frames, shape (T, J) in [0, 1] (> 0.5 = flagged)."""
        from .repair import map_to_input

        out = self.clean(motion, context)
        return map_to_input(out.map_result(), motion)

    def repair(self, motion: Motion, context: Any = None, contacts: Sequence[Any] = ()) -> tuple[Motion, Any]:
        """Cleaned motion (input frame rate) and the edits as an Arrow table."""
        out = self.clean(motion, context, contacts)
        return out.cleaned, out.edits

    def clean_clip(self, motion: Motion, context: Any, clip_id: int, out_dir: Any = None, registries: Any = None) -> Any:
        """One clip of the default step (analysis once; BVH, heatmap and plots into ``out_dir``)."""
        from mocapflow.framework.cleaning import CleanedClip

        from .clean_clip import clean_clip

        out = clean_clip(self, motion, context, clip_id, out_dir, registries)
        return CleanedClip(out["mdm"], out["edits"], out["cleaned"], out["summary"])
