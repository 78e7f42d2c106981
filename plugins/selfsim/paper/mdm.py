"""The movement digression map (MDM) of Aristidou et al. 2018: the analysis of ``cleaners.mdm``.

Pipeline of one clip (paper section in brackets):

1. resample to 24 fps, drop the root translation, align the facing direction, take the
   texture of the 24 most informative joints (§3.1, §5 Implementation);
2. source words of 15 frames every 5 frames, target words of 20 frames at every context
   frame, compared per joint group by constrained DTW over eq. 1 (§3.2, Appendix);
3. KNN = the K = 5 smallest local minima of each word's distance function, away from the
   word itself (§3.3), found exactly by :mod:`.knn`;
4. mean-motion-texture T̄ (chordal quaternion mean of every KNN word covering a cell),
   ``M = |T - T̄|`` as a geodesic angle, each joint's row divided by its mean (floored at
   :data:`MEAN_FLOOR`, so a joint the capture never rotates is not scaled up to 1
   everywhere) and ``MDM = 1 - exp(-M^2)`` (§3.4).

``mode: paper`` repairs the cells above 0.5 from the median KNN word (§4, :mod:`.repair`);
``mode: calibrated`` decides on the same analysis with a detector fitted on the clean
context (:mod:`..calibrated`). Contexts (§3.1, §5): ``None`` (the clip itself), a Motion,
a list of Motions or a :class:`~mocapflow.framework.database.MotionDatabase`; the clip is
added to its context unless ``include_self`` is off.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from mocapflow.framework import quaternions as quat
from mocapflow.framework.errors import DataError
from mocapflow.framework.motion import Motion

from .knn import ContextTextures, WordNeighbours, knn_search
from .motion_words import Texture, context_motions, motion_texture, resolve_groups, source_word_starts

if TYPE_CHECKING:
    from ..cleaner import MDMParams

__all__ = ["DigressionResult", "context_motions", "digression_map"]

#: Floor of the row mean of ``M`` (radians): a joint whose difference is numerically zero
#: everywhere is not blown up to 1.
MEAN_FLOOR = 0.01


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
        The KNN search (empty when the clip is shorter than one word).
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
    if params is None:
        from ..cleaner import MDMParams

        params = MDMParams()
    p = params
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
