"""Bounded repair of capture noise: a low-pass toward the KNN consensus (session 6, round 2).

Replacing a noisy run by the KNN word (:mod:`.bounded_repair`) is right for a real burst of
noise and harmful where the jitter cue fires on a clean fast joint (a wrist at a swing's
turn: up to 30 degrees of clean motion replaced). This repair only removes what *is*
noise by the take's own evidence:

1. the take's deviation from its consensus, ``d_t = log(T̄_t^-1 q_t)`` (rotation vector), is
   low-passed by a moving mean over ``2 half + 1`` frames; ``T̄_t exp(LP d_t)`` keeps the
   consensus' fast shape (a knee at heel strike) and the take's slow departures from it;
2. the *noise amplitude* of a cell is the RMS over the same window of the high-pass residual
   ``|d - LP d|``; its null is the joint's own median amplitude over the take (most cells are
   clean: the protocol's density is 12-15 % of words);
3. a cell moves toward the low-passed value by at most its amplitude beyond ``factor`` times
   the null (floored at :data:`AMP_FLOOR`; 0 on a clean cell, which is then left exactly as it was), and only when that
   brings it nearer T̄.
"""
from __future__ import annotations

import numpy as np

from mocapflow.framework import quaternions as quat

from .cues import rotation_vectors

#: Least null amplitude, radians: a joint whose deviation from T̄ is smooth everywhere has a
#: median amplitude near 0, and twice that is exceeded wherever its slow departure bends;
#: capture noise of the protocol (sd 15 degrees a frame) has amplitudes of 10-25 degrees.
AMP_FLOOR = np.deg2rad(1.0)


def rotation_exp(v: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) of rotation vectors (..., 3), radians (inverse of
    :func:`.cues.rotation_vectors`)."""
    ang = np.linalg.norm(v, axis=-1, keepdims=True)
    half = 0.5 * ang
    # sin(a/2)/a -> 1/2 as a -> 0
    k = np.where(ang > 1e-12, np.sin(half) / np.where(ang > 1e-12, ang, 1.0), 0.5)
    return np.concatenate([np.cos(half), k * v], axis=-1)


def window_mean(x: np.ndarray, half: int) -> np.ndarray:
    """Mean over ``[t - half, t + half]`` along axis 0 (shrunk at the ends), any trailing shape."""
    t = len(x)
    c = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)], axis=0)
    lo = np.clip(np.arange(t) - half, 0, t)
    hi = np.clip(np.arange(t) + half + 1, 0, t)
    n = (hi - lo).reshape((t,) + (1,) * (x.ndim - 1))
    return (c[hi] - c[lo]) / n


def lowpassed(q: np.ndarray, mean_q: np.ndarray, half: int) -> tuple[np.ndarray, np.ndarray]:
    """The low-passed take and each cell's noise amplitude.

    Parameters
    ----------
    q, mean_q : ndarray of shape (T, m, 4)
        Take and its KNN consensus T̄ (unit quaternions).
    half : int
        Half window, frames.

    Returns
    -------
    target : ndarray of shape (T, m, 4)
        ``T̄ exp(LP d)``, hemisphere of ``q``.
    amplitude : ndarray of shape (T, m)
        RMS of ``|d - LP d|`` over the window, radians.
    """
    d = rotation_vectors(quat.normalize(quat.mul(quat.conjugate(mean_q), q)))
    s = window_mean(d, half)
    r2 = np.sum((d - s) ** 2, axis=-1)
    amp = np.sqrt(window_mean(r2, half))
    target = quat.normalize(quat.mul(mean_q, rotation_exp(s)))
    target = np.where(np.sum(target * q, -1, keepdims=True) < 0, -target, target)
    return target, amp


def noise_cap(q: np.ndarray, mean_q: np.ndarray, half: int = 2, factor: float = 2.0,
              floor: float = AMP_FLOOR) -> np.ndarray:
    """Per cell, the noise amplitude beyond ``factor`` times the joint's null (its median
    amplitude over the take, at least ``floor``), radians, (T, m): the most a noise repair may
    move the cell (``noise_fix: capped`` bounds the KNN repair of a jitter run by it)."""
    _, amp = lowpassed(q, mean_q, half)
    null = np.maximum(np.median(amp, axis=0, keepdims=True), floor)
    return np.maximum(amp - factor * null, 0.0)


def word_null(res, half: int = 2) -> np.ndarray:
    """Per cell, the median over the KNN words of *their* noise amplitude against T̄ at that
    frame, radians, (T, m) (NaN where no word covers the cell).

    T̄ averages the warped KNN words and is smoother than any of them: a fast clean joint's
    deviation from it has high-frequency energy, and so has each clean KNN word's. The
    words of the frame's nearest word centre (first joint group holding the joint, every
    valid neighbour) are scored with :func:`lowpassed` against T̄ over the word's frames."""
    mean_q = res.mean_texture
    t_count, m = mean_q.shape[:2]
    out = np.full((t_count, m), np.nan)
    if not res.neighbours:
        return out
    neigh = res.neighbours[0]
    n = neigh.warped.shape[3]
    starts = neigh.starts
    centres = starts + (n - 1) / 2.0
    amp_of: dict[tuple[int, int], np.ndarray] = {}
    for f in range(t_count):
        cover = np.flatnonzero((starts <= f) & (f < starts + n))
        if not len(cover):
            continue
        w = int(cover[np.argmin(np.abs(centres[cover] - f))])
        s0 = int(starts[w])
        for j in range(m):
            holders = np.flatnonzero(neigh.groups.mask[:, j])
            if not len(holders):
                continue
            g = int(holders[0])
            if (g, w) not in amp_of:
                valid = neigh.target[g, w] >= 0
                words = neigh.warped[g, w][valid]  # (k, N, m, 4)
                if not len(words):
                    amp_of[(g, w)] = np.full((n, m), np.nan)
                else:
                    ref = np.broadcast_to(mean_q[s0:s0 + n], words.shape)
                    amps = np.stack([lowpassed(wd, r, half)[1] for wd, r in zip(words, ref)])
                    amp_of[(g, w)] = np.median(amps, axis=0)
            out[f, j] = amp_of[(g, w)][f - s0, j]
    return out


def noise_repair(q: np.ndarray, mean_q: np.ndarray, mask: np.ndarray, half: int = 2,
                 factor: float = 2.0, floor: float = AMP_FLOOR) -> tuple[np.ndarray, np.ndarray]:
    """Noise repair of the ``mask`` cells (see the module docstring).

    Parameters
    ----------
    q, mean_q : ndarray of shape (T, m, 4)
        Take and its KNN consensus.
    mask : ndarray of bool, shape (T, m)
        Cells to repair (those the jitter cue decided).
    half : int
        Half window of the low-pass and of the amplitude, frames.
    factor : float
        Multiple of the joint's median amplitude (its null) an amplitude must exceed.
    floor : float
        Least null, radians.

    Returns
    -------
    new : ndarray of shape (T, m, 4)
        ``q`` with the repaired cells replaced; every other cell bit-identical.
    edited : ndarray of bool, shape (T, m)
    """
    new = q.copy()
    if not mask.any() or len(q) < 3:
        return new, np.zeros(mask.shape, bool)
    target, amp = lowpassed(q, mean_q, half)
    null = np.maximum(np.median(amp, axis=0, keepdims=True), floor)
    cap = np.maximum(amp - factor * null, 0.0)  # as noise_cap
    move = quat.geodesic_angle(q, target)
    frac = np.where(move > cap, cap / np.where(move > 0, move, 1.0), 1.0)
    cand = quat.slerp(q, target, frac)
    ok = mask & (cap > 0) & (move > 0)
    ok &= quat.geodesic_angle(cand, mean_q) < quat.geodesic_angle(q, mean_q) - 1e-9
    new[ok] = cand[ok]
    return new, ok
