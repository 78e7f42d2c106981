"""Fast exact K-nearest motion-words (Aristidou 2018 §3.2-3.3) with lower-bound pruning.

Eq. 1 is computed once per (source frame, context frame) pair and joint group in blocks, the
constrained DTW in compiled kernels, and a lower bound of the word distance
(:mod:`._mdm_kernels`) orders the target starts and stops the search once no start can
enter the KNN: the answer equals the brute force (``tests/naive/cleaning.py``). The KNN of
a source word are the ``K`` smallest local minima of its distance over the context's target
starts (per clip), minima within ``radius`` frames of the source word itself left out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from mocapflow.framework.errors import DataError

from .motion_words import JointGroups, target_word_layout


@dataclass(frozen=True)
class ContextTextures:
    """Textures of the context clips concatenated frame-wise: ``q`` (C, m, 4), sign-continuous
    within each clip; ``clip_lengths`` (n_clips,) int64; ``names``."""

    q: np.ndarray
    clip_lengths: np.ndarray
    names: tuple[str, ...]

    @classmethod
    def from_arrays(cls, textures: Sequence[np.ndarray], names: Sequence[str] | None = None) -> ContextTextures:
        if not textures:
            raise DataError("the cleaning context holds no clip")
        m = textures[0].shape[1]
        if any(t.ndim != 3 or t.shape[1:] != (m, 4) for t in textures):
            raise DataError(f"context textures must all be (T, {m}, 4)")
        q = np.ascontiguousarray(np.concatenate(textures, axis=0), dtype=np.float64)
        names = tuple(names) if names is not None else tuple(str(i) for i in range(len(textures)))
        return cls(q, np.array([len(t) for t in textures], np.int64), names)

    @property
    def offsets(self) -> np.ndarray:
        """First context frame of each clip, shape (n_clips + 1,)."""
        return np.concatenate([[0], np.cumsum(self.clip_lengths)]).astype(np.int64)


@dataclass
class WordNeighbours:
    """The KNN of every source word for every joint group: ``starts`` (S,) source word
    starts; ``target`` (G, S, K) int64 context frame of each neighbour word (-1: fewer than K
    minima); ``distance`` (G, S, K) mean pose distance along the DTW path, ascending (inf:
    none); ``warped`` (G, S, K, N, m, 4) each neighbour's warped target word at the source
    length; ``n_dtw`` DTWs computed.
    """

    starts: np.ndarray
    groups: JointGroups
    target: np.ndarray
    distance: np.ndarray
    warped: np.ndarray
    n_dtw: int = 0


def warp_sequences(seq: np.ndarray, n: int) -> np.ndarray:
    """Resample quaternion sequences ``(p, ...)`` along time to ``n`` frames (polyphase
    filter, scipy's default Kaiser FIR), renormalised to unit quaternions."""
    p = len(seq)
    if p != n:
        g = np.gcd(n, p)
        # time on the last, contiguous axis: upfirdn is much faster there
        flat = np.ascontiguousarray(seq.reshape(p, -1).T)
        # 'line' padding: quaternion components are smooth, zero padding would shrink the ends
        from scipy.signal import resample_poly  # lazy: scipy.signal costs seconds at import

        out = resample_poly(flat, n // g, p // g, axis=-1, padtype="line")
        seq = np.ascontiguousarray(out.T).reshape((n,) + seq.shape[1:])
    norm = np.linalg.norm(seq, axis=-1, keepdims=True)
    return seq / np.where(norm > 0, norm, 1.0)


def knn_search(
    source_q: np.ndarray,
    context: ContextTextures,
    groups: JointGroups,
    *,
    self_clip: int = -1,
    source_length: int = 15,
    target_length: int = 20,
    word_starts: np.ndarray,
    k: int = 5,
    slope_run: int = 2,
    radius: int | None = None,
    block_rows: int = 192,
) -> WordNeighbours:
    """K nearest target words of each source word of ``source_q`` (T, m, 4), per joint group.

    ``self_clip``: position of the source clip in ``context`` (-1: absent), whose minima
    within ``radius`` frames (None: N // 2, the paper's N/2) of the source word are left out;
    ``word_starts`` (S,) increasing; ``slope_run``: most consecutive non-diagonal DTW steps;
    ``block_rows``: source frames per eq. 1 block (memory G * block_rows * C * 4 bytes).
    """
    from . import _mdm_kernels as kern

    n, mlen = int(source_length), int(target_length)
    if source_q.shape[1:] != context.q.shape[1:]:
        raise DataError(f"source texture {source_q.shape[1:]} and context {context.q.shape[1:]} differ in joints")
    if not 1 <= n <= mlen:
        raise DataError(f"need 1 <= source length ({n}) <= target length ({mlen})")
    starts = np.asarray(word_starts, np.int64)
    if len(starts) and (starts.min() < 0 or starts.max() + n > len(source_q)):
        raise DataError("source words must lie inside the source clip")
    radius = n // 2 if radius is None else int(radius)
    tlen, clip_of = target_word_layout(context.clip_lengths, n, mlen)
    self_off = int(context.offsets[self_clip]) if self_clip >= 0 else 0
    g_count, s_count, m = groups.n_groups, len(starts), source_q.shape[1]
    target = np.full((g_count, s_count, k), -1, np.int64)
    distance = np.full((g_count, s_count, k), np.inf)
    warped = np.zeros((g_count, s_count, k, n, m, 4))
    n_dtw = 0
    jobs: dict[int, list[tuple[int, int, int, np.ndarray]]] = {}
    src = np.ascontiguousarray(source_q, dtype=np.float64)
    mask = groups.mask.astype(np.uint8)
    drop = groups.drop.astype(np.int64)
    for chunk in _word_chunks(starts, n, block_rows):
        r0, r1 = int(starts[chunk[0]]), int(starts[chunk[-1]]) + n
        d = np.empty((g_count, r1 - r0, len(context.q)), np.float32)
        kern.pose_distance_block(src[r0:r1], context.q, mask, drop, d)
        st = starts[chunk]
        out_t = np.empty((g_count, len(st), k), np.int64)
        out_d = np.empty((g_count, len(st), k))
        w_rows = np.empty_like(d)
        kern.sliding_row_min(d, tlen, w_rows)
        v_cols = np.empty((g_count, len(st), d.shape[2]), np.float32)
        kern.word_column_min(d, st - r0, n, v_cols)
        lb = np.empty((g_count, len(st), d.shape[2]))
        kern.lower_bounds(w_rows, v_cols, st, r0, n, tlen, slope_run, lb)
        out_n = np.empty((g_count, len(st)), np.int64)
        kern.knn_pruned(d, lb, st, r0, n, tlen, clip_of, self_clip, self_off, radius, slope_run, k, out_t, out_d, out_n)
        n_dtw += int(out_n.sum())
        target[:, chunk] = out_t
        distance[:, chunk] = out_d
        for g in range(g_count):
            for a, w in enumerate(chunk):
                for b in range(k):
                    t = int(out_t[g, a, b])
                    if t < 0:
                        continue
                    _, path = kern.cdtw_path(d[g], int(st[a]) - r0, t, n, int(tlen[t]), slope_run)
                    jobs.setdefault(len(path), []).append((g, w, b, t + path[:, 1]))
    for items in jobs.values():
        # one polyphase call per path length instead of one per neighbour
        frames = np.stack([it[3] for it in items], axis=1)  # (p, B)
        out = warp_sequences(context.q[frames], n)  # (n, B, m, 4)
        for c, (g, w, b, _) in enumerate(items):
            warped[g, w, b] = out[:, c]
    return WordNeighbours(starts, groups, target, distance, warped, n_dtw)


def _word_chunks(starts: np.ndarray, n: int, block_rows: int) -> list[np.ndarray]:
    """Consecutive runs of words whose rows span at most ``max(block_rows, n)`` frames."""
    chunks: list[np.ndarray] = []
    cur: list[int] = []
    for w, s in enumerate(starts):
        if cur and s + n - starts[cur[0]] > max(block_rows, n):
            chunks.append(np.array(cur, np.int64))
            cur = []
        cur.append(w)
    if cur:
        chunks.append(np.array(cur, np.int64))
    return chunks
