"""Slow, obviously correct reference for the words cue of the calibrated cleaner
(:mod:`mocapflow.plugins.selfsim.word_noise`, session 7): the take's noise amplitude against
T̄ over the KNN words' amplitude, as scalar loops (the amplitude written out as in
:func:`naive.cleaning_noise.naive_noise_repair`)."""
from __future__ import annotations

import math

import numpy as np

from naive.cleaning_holds import _conj, _mul
from naive.cleaning_noise import _log, _unit


def naive_amplitude(q: np.ndarray, mean_q: np.ndarray, half: int) -> np.ndarray:
    """Per cell: d_t = log(mean_t^-1 q_t), s_t its mean over [t-half, t+half] (clipped),
    the RMS over the same window of |d - s|, radians, (T, m)."""
    t_count, m = q.shape[:2]
    out = np.zeros((t_count, m))
    for j in range(m):
        d = [_log(_unit(_mul(_conj(list(mean_q[t, j])), list(q[t, j])))) for t in range(t_count)]
        win = [range(max(0, t - half), min(t_count, t + half + 1)) for t in range(t_count)]
        s = [[sum(d[k][c] for k in w) / len(w) for c in range(3)] for w in win]
        r2 = [sum((d[t][c] - s[t][c]) ** 2 for c in range(3)) for t in range(t_count)]
        for t in range(t_count):
            out[t, j] = math.sqrt(sum(r2[k] for k in win[t]) / len(win[t]))
    return out


def naive_word_jitter(q: np.ndarray, mean_q: np.ndarray, word_amp: np.ndarray, half: int, slack: int,
                      floor: float = math.radians(1.0), erode: int = 0) -> np.ndarray:
    """Per cell: W = the largest finite word amplitude over [t-slack, t+slack] (none: the cue
    is 0), A = :func:`naive_amplitude`; the cue is max(log((A + floor) / (W + floor)), 0),
    then its smallest value over [t-erode, t+erode] (clipped at the ends)."""
    t_count, m = q.shape[:2]
    amp = naive_amplitude(q, mean_q, half)
    out = np.zeros((t_count, m))
    for j in range(m):
        for t in range(t_count):
            vals = [word_amp[k, j] for k in range(max(0, t - slack), min(t_count, t + slack + 1))
                    if not math.isnan(word_amp[k, j])]
            if vals:
                out[t, j] = max(math.log((amp[t, j] + floor) / (max(vals) + floor)), 0.0)
    if erode:
        out = np.array([[min(out[k, j] for k in range(max(0, t - erode), min(t_count, t + erode + 1)))
                         for j in range(m)] for t in range(t_count)])
    return out
