"""Adaptive segmentation (Müller et al. 2005, §4): F-segments are runs of maximal length.

For a selected subset of boolean features, consecutive frames with the same feature
vector form a run; the F-segments are the maximal runs, and they never cross a clip
boundary. Segments are half-open frame ranges ``[start, end)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np

from mocapflow.framework.errors import DataError


def pack_codes(bits: np.ndarray, columns: np.ndarray | list[int] | None = None) -> np.ndarray:
    """Integer code (T,) int64 per frame of the selected columns (at most 63; default all) of
    ``bits`` (T, f), bool or 0/1: bit ``i`` = ``columns[i]``."""
    b = np.asarray(bits)
    if b.ndim != 2:
        raise DataError(f"feature bits must be (n_frames, n_features), got shape {b.shape}")
    cols = np.arange(b.shape[1]) if columns is None else np.asarray(columns, dtype=np.int64)
    if len(cols) > 63:
        raise DataError(f"at most 63 features can be packed into one code, got {len(cols)}")
    sel = b[:, cols] if b.dtype == bool else b[:, cols] > 0.5
    if len(cols) == 0:
        return np.zeros(len(b), np.int64)
    # one pass: pack the bits little-endian into bytes, then read the bytes as an integer
    packed = np.packbits(sel, axis=1, bitorder="little")
    width = {1: np.uint8, 2: np.uint16}.get(packed.shape[1])
    if width is not None:
        return np.ascontiguousarray(packed).view(width).reshape(-1).astype(np.int64)
    pad = np.zeros((len(b), 8), np.uint8)
    pad[:, : packed.shape[1]] = packed
    return pad.view("<u8").reshape(-1).astype(np.int64)


@dataclass(frozen=True)
class Segmentation:
    """F-segments of concatenated clips, each (K,) int64: the global frame range ``[start,
    end)``, the feature vector as an integer (``code``, :func:`pack_codes`) and the clip
    position (0-based index into the offsets)."""

    start: np.ndarray
    end: np.ndarray
    code: np.ndarray
    clip: np.ndarray

    def __len__(self) -> int:
        return len(self.start)

    @property
    def lengths(self) -> np.ndarray:
        return cast("np.ndarray", self.end - self.start)

    @property
    def clip_first(self) -> np.ndarray:
        """True for the first segment of each clip, shape (K,)."""
        first = np.ones(len(self), dtype=bool)
        first[1:] = self.clip[1:] != self.clip[:-1]
        return first


def segment_codes(codes: np.ndarray, offsets: np.ndarray | None = None) -> Segmentation:
    """Maximal runs of equal ``codes`` (T,), split at clip ``offsets`` (n_clips + 1,; default
    one clip); vectorised, linear time."""
    codes = np.asarray(codes, dtype=np.int64)
    t = len(codes)
    offsets = np.array([0, t], dtype=np.int64) if offsets is None else np.asarray(offsets, dtype=np.int64)
    if offsets[0] != 0 or offsets[-1] != t or np.any(np.diff(offsets) < 0):
        raise DataError(f"clip offsets must rise from 0 to {t}, got {offsets[:3]}...{offsets[-1:]}")
    if t == 0:
        z = np.zeros(0, dtype=np.int64)
        return Segmentation(z, z, z, z)
    brk = np.zeros(t, dtype=bool)
    brk[0] = True
    brk[1:] = codes[1:] != codes[:-1]
    brk[offsets[:-1][np.diff(offsets) > 0]] = True
    start = np.flatnonzero(brk).astype(np.int64)
    end = np.append(start[1:], t)
    clip = np.searchsorted(offsets, start, side="right") - 1
    return Segmentation(start, end, codes[start], clip.astype(np.int64))


def segment(
    bits: np.ndarray, columns: np.ndarray | list[int] | None = None, offsets: np.ndarray | None = None
) -> Segmentation:
    """F-segmentation of ``bits`` (T, f) of concatenated clips split at ``offsets``, for the
    feature ``columns`` (the combined feature function F; default all): ``code`` bit ``i``
    is feature ``columns[i]``."""
    return segment_codes(pack_codes(bits, columns), offsets)


def offsets_from_clip_ids(clip_id: np.ndarray) -> np.ndarray:
    """Clip offsets of frame rows grouped by clip (clip ids change only at a boundary)."""
    clip_id = np.asarray(clip_id)
    if len(clip_id) == 0:
        return np.zeros(1, dtype=np.int64)
    starts = np.flatnonzero(np.r_[True, clip_id[1:] != clip_id[:-1]])
    return np.append(starts, len(clip_id)).astype(np.int64)


__all__ = ["Segmentation", "offsets_from_clip_ids", "pack_codes", "segment", "segment_codes"]
