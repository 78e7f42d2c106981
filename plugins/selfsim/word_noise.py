"""A jitter cue whose null is the KNN words' own high-frequency energy (session 7, issue 14).

The jitter cue of :mod:`.cues` is the take's acceleration beyond the consensus' (``T̄``'s),
in units of the joint's typical acceleration. ``T̄`` averages the warped KNN words and is
smoother than any one of them, so a fast clean joint (a wrist at a swing's turn) has more
acceleration than ``T̄`` and the cue's null level must be high; lowering it (the jitter
floors of session 6) flags clean fast joints and leaves the wrist noise the protocol
injects (sd 15 degrees a frame) only partly above it.

Here the expected high-frequency energy of a cell is measured on the KNN words
themselves, at the same frames and against the same reference:

1. the *noise amplitude* of a sequence ``x`` against ``T̄`` (:func:`.noise.lowpassed`) is the
   RMS over ``2 half + 1`` frames of the high-pass residual of ``d = log(T̄^-1 x)``;
2. the take's amplitude ``A`` and, per cell, the median amplitude ``W`` of the valid
   neighbours of the word whose centre is nearest the frame, for the first joint group
   holding the joint (:func:`word_amplitude`, the vectorised :func:`.noise.word_null`),
   optionally its largest value over ``+-slack`` frames (a warped word may place a clean
   turn a frame away from the take's);
3. the cue is ``log((A + a0) / (W + a0))`` (``a0`` = :data:`.noise.AMP_FLOOR`), 0 where no
   word covers the cell: a clean take is about as rough as its neighbours (cue near 0), a
   noisy run is much rougher than they are, whatever the joint's speed; optionally eroded
   (its smallest value over ``+-erode`` frames) so a short spike's leak into its clean
   neighbours does not set the null.

The calibration fits this cue's per-joint null and weight like every other cue's
(:mod:`.calibration`, ``cues: [..., words]`` or a floor ``cue_fa: {words: ...}``).
"""
from __future__ import annotations

import numpy as np

from mocapflow.framework import quaternions as quat

from .cues import rotation_vectors
from .noise import AMP_FLOOR, lowpassed, window_mean


def _window_mean_axis(x: np.ndarray, half: int, axis: int) -> np.ndarray:
    """:func:`.noise.window_mean` along ``axis`` (a word's frames, not the first axis)."""
    return np.moveaxis(window_mean(np.moveaxis(x, axis, 0), half), 0, axis)


def word_amplitude(neigh, mean_q: np.ndarray, half: int = 2) -> np.ndarray:
    """Per cell, the median noise amplitude of the KNN words against ``T̄``, radians.

    Parameters
    ----------
    neigh : WordNeighbours (:mod:`.knn`)
        ``warped`` of shape (G, S, K, N, m, 4), ``target`` (G, S, K), ``starts`` (S,),
        ``groups.mask`` (G, m).
    mean_q : ndarray of shape (T, m, 4)
        ``T̄``.
    half : int
        Half window of the amplitude, frames (within each word's N frames).

    Returns
    -------
    ndarray of shape (T, m)
        NaN where no word covers the frame, no group holds the joint or no neighbour is
        valid. Same values as :func:`.noise.word_null`.
    """
    t_count, m = mean_q.shape[:2]
    out = np.full((t_count, m), np.nan)
    starts = np.asarray(neigh.starts, np.int64)
    if not len(starts):
        return out
    n = neigh.warped.shape[3]
    mask = np.asarray(neigh.groups.mask, bool)
    has_group = mask.any(axis=0)
    g_of = np.argmax(mask, axis=0)  # first group holding each joint
    cols = np.arange(m)
    # (m, S, K, N, 4) -> (S, K, N, m, 4): each joint's column from its own group's words
    words = np.moveaxis(neigh.warped[g_of, :, :, :, cols], 0, 3)
    valid = np.moveaxis(neigh.target[g_of] >= 0, 0, 2)  # (S, K, m)
    frames = starts[:, None] + np.arange(n)[None, :]  # (S, N)
    ref = mean_q[frames][:, None]  # (S, 1, N, m, 4)
    d = rotation_vectors(quat.normalize(quat.mul(quat.conjugate(np.broadcast_to(ref, words.shape)), words)))
    s = _window_mean_axis(d, half, 2)
    amp = np.sqrt(_window_mean_axis(np.sum((d - s) ** 2, axis=-1), half, 2))  # (S, K, N, m)
    amp = np.where(valid[:, :, None, :], amp, np.nan)
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN slices: no valid neighbour
            med = np.nanmedian(amp, axis=1)  # (S, N, m)
    f = np.arange(t_count)
    cover = (starts[None, :] <= f[:, None]) & (f[:, None] < starts[None, :] + n)
    dist = np.where(cover, np.abs(starts[None, :] + (n - 1) / 2.0 - f[:, None]), np.inf)
    w = np.argmin(dist, axis=1)  # first of the nearest centres
    ok = cover.any(axis=1)
    rows = med[w[ok], f[ok] - starts[w[ok]]]  # (T_ok, m)
    out[ok] = np.where(has_group[None, :], rows, np.nan)
    return out


def slack_max(x: np.ndarray, slack: int) -> np.ndarray:
    """Largest value over ``[t - slack, t + slack]`` along time, NaN ignored (NaN where all are)."""
    if slack <= 0:
        return x
    out = x.copy()
    for o in range(1, slack + 1):
        out[o:] = np.fmax(out[o:], x[:-o])
        out[:-o] = np.fmax(out[:-o], x[o:])
    return out


def word_jitter(q: np.ndarray, mean_q: np.ndarray, word_amp: np.ndarray, half: int = 2, slack: int = 0,
                floor: float = AMP_FLOOR, erode: int = 0) -> np.ndarray:
    """The raw cue ``log((A + a0) / (W + a0))``, clipped at 0, shape (T, m) (module doc).

    Parameters
    ----------
    q, mean_q : ndarray of shape (T, m, 4)
        Take and ``T̄``.
    word_amp : ndarray of shape (T, m)
        :func:`word_amplitude` (NaN = no word: the cue is 0 there).
    half : int
        Half window of the take's amplitude (as ``word_amp``'s).
    slack : int
        ``W`` is its largest value over ``+-slack`` frames.
    floor : float
        ``a0``, radians.
    erode : int
        The cue is its smallest value over ``+-erode`` frames: the windowed amplitude of a
        1-3 frame spike leaks ``2 half`` frames to each side (into clean cells), a burst of
        noise of 8 frames or more keeps its middle.
    """
    amp = lowpassed(q, mean_q, half)[1]
    w = slack_max(word_amp, slack)
    have = np.isfinite(w)
    out = np.maximum(np.log((amp + floor) / (np.where(have, w, amp) + floor)), 0.0)  # 0 where no word covers
    if erode > 0:
        from .cues import window_min

        out = window_min(out, erode)
    return out
