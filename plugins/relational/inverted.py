"""Inverted-list indexes of relational feature segments (Müller et al. 2005, §5.1 and §5.3).

One index per feature set (F_l: 11 features, F_u: 12, F_m: 8). The database is one long
document: its F-segmentation (maximal runs of equal feature vectors, split at clip
boundaries) gives the segment sequence ``w_1 .. w_M``; the inverted list ``L(v)`` holds
the positions ``k`` (0-based here) with ``w_k = v``, sorted ascending. Only non-empty lists
are stored (at most ``2**f``).

Build time is linear in the number of frames: segmentation is one vectorised pass and the
lists come from a stable sort of the segment codes, which NumPy performs as a radix sort
for integer keys of 16 bits or less (every set here has at most 12 bits).

On disk (``<dataset>/index/``): per set ``<set>_segments.parquet`` (segment, clip_id,
start_frame, end_frame exclusive, code) and ``<set>_lists.parquet`` (code, positions), plus
``clips.parquet`` (clip_id, offset) and ``meta.json``.

Query API
---------
This index does not answer the numeric kNN contract of :class:`Index` (``query`` raises);
it is queried through :class:`SetIndex` (``positions(code)``, ``union(codes)``,
``segment frame ranges``) by ``matchers.relational``, which implements exact, fuzzy,
adaptive fuzzy and m-mismatch hits on top of it. Load it with ``InvertedIndex.load(dir)``
or ``Dataset.index()``; ``index.sets["lower" | "upper" | "mixed"]`` is a :class:`SetIndex`.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar, cast

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from pydantic import Field

from mocapflow.framework.components import Index
from mocapflow.framework.components import Params as BaseParams
from mocapflow.framework.errors import ConfigError, DataError, PipelineError

from .feature_table import FEATURE_IDS, SET_SLICES, SETS
from .segmentation import offsets_from_clip_ids, pack_codes, segment_codes

if TYPE_CHECKING:  # pragma: no cover
    from mocapflow.framework.context import StepContext
    from mocapflow.framework.datasets import Dataset, StepOutput


@dataclass
class SetIndex:
    """The inverted lists of one feature set (``name`` lower, upper or mixed; ``columns`` (f,)
    of the 31 features, bit ``i`` of a code = ``columns[i]``), with the segments they point
    to: ``seg_start, seg_end, seg_code, seg_clip`` (M,) int64, the global frame range
    ``[start, end)``, code and clip position of each; ``clip_offsets`` (n_clips + 1,) the
    global first frame of each clip; ``list_codes`` (n_lists,) the codes with a non-empty
    list, ascending; list ``i`` is ``list_positions[list_offsets[i]:list_offsets[i + 1]]``.
    """

    name: str
    columns: np.ndarray
    seg_start: np.ndarray
    seg_end: np.ndarray
    seg_code: np.ndarray
    seg_clip: np.ndarray
    clip_ids: np.ndarray
    clip_offsets: np.ndarray
    list_codes: np.ndarray
    list_offsets: np.ndarray
    list_positions: np.ndarray

    @cached_property
    def list_frames(self) -> np.ndarray:
        """Frames covered by each inverted list (aligned with ``list_codes``), int64."""
        lengths = (self.seg_end - self.seg_start)[self.list_positions]
        if not len(lengths):
            return np.zeros(len(self.list_codes), np.int64)
        return np.add.reduceat(lengths, self.list_offsets[:-1]) * (np.diff(self.list_offsets) > 0)

    @property
    def n_segments(self) -> int:
        return len(self.seg_start)

    @property
    def n_features(self) -> int:
        return len(self.columns)

    @classmethod
    def build(
        cls, name: str, codes: np.ndarray, columns: np.ndarray, clip_ids: np.ndarray, clip_offsets: np.ndarray
    ) -> SetIndex:
        """Segment frame codes and build the inverted lists (linear time)."""
        seg = segment_codes(codes, clip_offsets)
        dtype = np.uint16 if len(columns) <= 16 else np.int64
        order = np.argsort(seg.code.astype(dtype), kind="stable")  # radix sort: linear
        sorted_codes = seg.code[order]
        brk = (
            np.flatnonzero(np.r_[True, sorted_codes[1:] != sorted_codes[:-1]]) if len(order) else np.zeros(0, np.int64)
        )
        return cls(
            name,
            np.asarray(columns, np.int64),
            seg.start,
            seg.end,
            seg.code,
            seg.clip,
            np.asarray(clip_ids, np.int32),
            np.asarray(clip_offsets, np.int64),
            sorted_codes[brk].astype(np.int64),
            np.append(brk, len(order)).astype(np.int64),
            order.astype(np.int64),
        )

    def positions(self, code: int) -> np.ndarray:
        """The inverted list ``L(code)``: sorted segment positions (empty if absent)."""
        i = np.searchsorted(self.list_codes, code)
        if i < len(self.list_codes) and self.list_codes[i] == code:
            return self.list_positions[self.list_offsets[i] : self.list_offsets[i + 1]]
        return self.list_positions[:0]

    def union(self, codes: np.ndarray) -> np.ndarray:
        """``L(V)``: the sorted union of the lists of a set of codes (eq. 11)."""
        codes = np.asarray(codes, dtype=np.int64)
        i = np.searchsorted(self.list_codes, codes)
        ok = i < len(self.list_codes)
        ok[ok] = self.list_codes[i[ok]] == codes[ok]
        parts = [self.list_positions[self.list_offsets[j] : self.list_offsets[j + 1]] for j in i[ok]]
        if not parts:
            return self.list_positions[:0]
        if len(parts) == 1:
            return parts[0]
        total = sum(len(x) for x in parts)
        if total * 8 < self.n_segments:  # few positions: sorting them is cheaper than a bitmap
            return np.sort(np.concatenate(parts))
        mark = np.zeros(self.n_segments, dtype=bool)
        for x in parts:
            mark[x] = True
        return np.flatnonzero(mark)

    # --- hits (§5.1, §5.2) -------------------------------------------------------
    def _same_clip(self, starts: np.ndarray, last: np.ndarray) -> np.ndarray:
        return cast("np.ndarray", self.seg_clip[starts] == self.seg_clip[last])

    def exact(self, codes: np.ndarray) -> np.ndarray:
        """Exact hits ``H(F[Q])`` (eq. 7) of the query's codes ``v_1 .. v_L`` (L,): intersection
        of the shifted lists ``L(v_l) - l``. Returns the start segment ``k`` (n_hits,) int64 of
        each hit, ascending (0-based; the hit covers segments ``k .. k+L-1`` of one clip)."""
        return self._intersect([self.positions(int(c)) for c in codes])

    def fuzzy(self, member: np.ndarray) -> np.ndarray:
        """Fuzzy hits (eq. 11): intersection of shifted unions ``L(V_l) - l``.

        ``member`` is a boolean table of shape (L, 2**f): ``member[l, c]`` iff code ``c`` is
        an alternative of the l-th query vector. Returns start segments as :meth:`exact`.
        """
        return self._intersect([self.union(np.flatnonzero(row)) for row in member])

    def _intersect(self, lists: list[np.ndarray]) -> np.ndarray:
        n_levels = len(lists)
        if not n_levels:
            return np.zeros(0, np.int64)
        # start from the shortest list; probe the others by binary search (no shifted copies)
        order = np.argsort([len(x) for x in lists], kind="stable")
        cand = lists[order[0]] - order[0]
        for i in order[1:]:
            if not len(cand):
                break
            other = lists[i]
            j = np.searchsorted(other, cand + i)
            ok = j < len(other)
            ok[ok] = other[j[ok]] == cand[ok] + i
            cand = cand[ok]
        cand = cand[(cand >= 0) & (cand + n_levels - 1 < self.n_segments)]
        return cast("np.ndarray", cand[self._same_clip(cand, cand + n_levels - 1)].astype(np.int64))

    def runs(self, codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Maximal runs of segments whose code is in ``codes``, never crossing a clip boundary:
        ``start, end`` (n_runs,) int64, the segment range ``[start, end)`` of each, ascending."""
        p = self.union(codes)
        if not len(p):
            return p.astype(np.int64), p.astype(np.int64)
        first = self.clip_first
        new = np.r_[True, p[1:] != p[:-1] + 1] | first[p]
        begin = np.flatnonzero(new)
        end_idx = np.append(begin[1:], len(p)) - 1
        return p[begin].astype(np.int64), p[end_idx].astype(np.int64) + 1

    def adaptive(self, member: np.ndarray) -> np.ndarray:
        """Adaptive fuzzy hits (§5.2): the segmentation is coarsened to maximal runs of each ``V_l``.

        The runs of ``V_1`` come from the union of its inverted lists; a compiled kernel then
        follows each candidate: the next run must start exactly where the previous ended
        (same clip, code in ``V_l``) and is extended segment by segment, so the work after
        the first level is proportional to the candidates' run lengths, not to the index.

        ``member`` (L, 2**f) bool: fuzzy sets with ``V_l`` and ``V_{l+1}`` disjoint
        (``coarsen_fuzzy``). Returns (n_hits, L + 1) int64 segment boundaries ``k_1 < ... <
        k_{L+1}`` per hit, level ``l`` covering ``[k_l, k_{l+1})`` (0-based; the paper's first
        example hit is ``k = (2, 3, 6, 7)`` 1-based).
        """
        n_levels = len(member)
        if n_levels == 0:
            return np.zeros((0, 1), np.int64)
        from ._match_kernels import adaptive_chain

        # candidates: the maximal runs of V_1, from the union of its inverted lists
        rs, re = self.runs(np.flatnonzero(member[0]))
        return adaptive_chain(rs, re, self.seg_code, self.clip_first, np.ascontiguousarray(member, dtype=bool))

    @cached_property
    def clip_first(self) -> np.ndarray:
        """True for each clip's first segment, shape (M,) (computed once)."""
        first = np.ones(self.n_segments, dtype=bool)
        first[1:] = self.seg_clip[1:] != self.seg_clip[:-1]
        return first

    def nbytes(self) -> int:
        """In-memory size of the index arrays (segments and lists), bytes."""
        return sum(
            a.nbytes
            for a in (
                self.seg_start,
                self.seg_end,
                self.seg_code,
                self.seg_clip,
                self.list_codes,
                self.list_offsets,
                self.list_positions,
            )
        )

    # --- persistence ---------------------------------------------------------------
    def segments_table(self) -> pa.Table:
        clip = self.seg_clip
        first = self.clip_offsets[clip]
        return pa.table(
            {
                "segment": pa.array(np.arange(self.n_segments, dtype=np.int32)),
                "clip_id": pa.array(self.clip_ids[clip].astype(np.int32)),
                "start_frame": pa.array((self.seg_start - first).astype(np.int32)),
                "end_frame": pa.array((self.seg_end - first).astype(np.int32)),
                "code": pa.array(self.seg_code.astype(np.int32)),
            }
        )

    def lists_table(self) -> pa.Table:
        return pa.table(
            {
                "code": pa.array(self.list_codes.astype(np.int32)),
                "positions": pa.ListArray.from_arrays(
                    pa.array(self.list_offsets.astype(np.int32)), pa.array(self.list_positions.astype(np.int32))
                ),
            }
        )

    def save(self, directory: Path) -> None:
        pq.write_table(self.segments_table(), directory / f"{self.name}_segments.parquet")
        pq.write_table(self.lists_table(), directory / f"{self.name}_lists.parquet")

    @classmethod
    def load(
        cls, directory: Path, name: str, columns: np.ndarray, clip_ids: np.ndarray, clip_offsets: np.ndarray
    ) -> SetIndex:
        seg = pq.read_table(directory / f"{name}_segments.parquet")
        lists = pq.read_table(directory / f"{name}_lists.parquet")
        # clip ids are sparse hashes (schema.clip_id_of): positions by sorted lookup, not by index
        order = np.argsort(clip_ids, kind="stable")
        seg_ids = seg["clip_id"].to_numpy()
        seg_clip = (
            order[np.searchsorted(clip_ids[order], seg_ids)] if len(clip_ids) else np.zeros(len(seg_ids), np.int64)
        )
        first = clip_offsets[seg_clip]
        col = lists["positions"].combine_chunks() if lists.num_rows else pa.array([], pa.list_(pa.int32()))
        return cls(
            name,
            columns,
            seg["start_frame"].to_numpy().astype(np.int64) + first,
            seg["end_frame"].to_numpy().astype(np.int64) + first,
            seg["code"].to_numpy().astype(np.int64),
            seg_clip,
            clip_ids,
            clip_offsets,
            lists["code"].to_numpy().astype(np.int64),
            col.offsets.to_numpy().astype(np.int64),
            col.values.to_numpy().astype(np.int64),
        )


class InvertedIndex(Index):
    """Inverted-list indexes I_l, I_u, I_m over the relational features (Müller et al. 2005, §5.3).

    Input: a ``features.relational`` dataset. ``sets`` (fitted) maps each set name to a
    :class:`SetIndex`. The numeric ``query(x, k)`` of the Index contract is not supported;
    use ``matchers.relational`` or the :class:`SetIndex` API (module docstring).
    """

    name = "inverted"
    supports_knn = False  # answers feature-sequence queries, not numeric kNN
    version = "1"
    set_names: ClassVar[tuple[str, ...]] = tuple(s[0] for s in SETS)

    class Params(BaseParams):
        feature_sets: tuple[str, ...] = Field(
            ("lower", "upper", "mixed"), description="feature sets to index (paper: all three)"
        )

    params: Params

    def build(self, features: np.ndarray, clip_id: np.ndarray | None = None, fps: float | None = None) -> InvertedIndex:
        """Build from the 31 relational features (T, 31) of concatenated clips; ``clip_id``
        (T,) per frame, rows grouped by clip (default one clip, id 0); ``fps`` is recorded."""
        x = np.asarray(features)
        if x.ndim != 2 or x.shape[1] != len(FEATURE_IDS):
            raise DataError(f"inverted index needs the {len(FEATURE_IDS)} relational features, got shape {x.shape}")
        unknown = set(self.params.feature_sets) - set(self.set_names)
        if unknown:
            raise ConfigError(f"indexes.inverted: unknown feature sets {sorted(unknown)}; choose from {self.set_names}")
        clip_id = np.zeros(len(x), np.int32) if clip_id is None else np.asarray(clip_id, np.int32)
        offsets = offsets_from_clip_ids(clip_id)
        ids = clip_id[offsets[:-1]] if len(clip_id) else np.zeros(0, np.int32)
        self.sets_: dict[str, SetIndex] = {}
        for name in self.params.feature_sets:
            cols = np.arange(SET_SLICES[name].start, SET_SLICES[name].stop)
            self.sets_[name] = SetIndex.build(name, pack_codes(x, cols), cols, ids, offsets)
        self.fps_ = fps
        return self

    @property
    def sets(self) -> dict[str, SetIndex]:
        if not hasattr(self, "sets_"):
            raise PipelineError("indexes.inverted: build() or load() the index first")
        return self.sets_

    def frame_bits(self) -> np.ndarray:
        """The indexed frames' 31 features, (T, 31) bool, expanded from the segments of every set.

        Needs all three sets (the segments of each cover every frame); used by queries that
        compare frames rather than segments (``matchers.relational`` mode ``auto``).
        """
        missing = [n for n, _, _ in SETS if n not in self.sets]
        if missing:
            raise ConfigError(
                f"indexes.inverted: frame features need all three feature sets; this index lacks {missing}"
            )
        any_set = self.sets[SETS[0][0]]
        out = np.zeros((int(any_set.clip_offsets[-1]), len(FEATURE_IDS)), bool)
        for s in self.sets.values():
            # the segments of a set tile the frames in order: expanding them gives frames 0..T-1
            codes = np.repeat(s.seg_code, s.seg_end - s.seg_start)
            for i, c in enumerate(s.columns):
                out[:, c] = (codes >> i) & 1
        return out

    def query(self, x: np.ndarray, k: int, radius: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError(
            "indexes.inverted answers segment queries, not kNN: use matchers.relational "
            "or index.sets[<set>].positions(code)"
        )

    def save(self, directory: Path) -> None:
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        any_set = next(iter(self.sets.values()))
        pq.write_table(
            pa.table({"clip_id": pa.array(any_set.clip_ids), "offset": pa.array(any_set.clip_offsets[:-1])}),
            directory / "clips.parquet",
        )
        meta = {
            "feature_sets": list(self.sets),
            "n_frames": int(any_set.clip_offsets[-1]),
            "fps": self.fps_,
            "columns": {n: s.columns.tolist() for n, s in self.sets.items()},
            "feature_ids": list(FEATURE_IDS),
            "params": self.get_params(),
        }
        (directory / "meta.json").write_text(json.dumps(meta, indent=1))
        for s in self.sets.values():
            s.save(directory)

    @classmethod
    def load(cls, directory: Path) -> InvertedIndex:
        directory = Path(directory)
        if not (directory / "meta.json").is_file():
            raise PipelineError(f"{directory} holds no inverted index (no meta.json)")
        meta = json.loads((directory / "meta.json").read_text())
        clips = pq.read_table(directory / "clips.parquet")
        ids = clips["clip_id"].to_numpy().astype(np.int32)
        offsets = np.append(clips["offset"].to_numpy().astype(np.int64), meta["n_frames"])
        self = cls(meta["params"])
        self.sets_ = {
            n: SetIndex.load(directory, n, np.asarray(meta["columns"][n], np.int64), ids, offsets)
            for n in meta["feature_sets"]
        }
        self.fps_ = meta.get("fps")
        return self

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        from mocapflow.framework.datasets import StepOutput

        feats = inputs["features"].features()
        if inputs["features"].producer != "features.relational":
            raise PipelineError(
                f"indexes.inverted needs a features.relational dataset, got {inputs['features'].producer}"
            )
        self.build(feats.x, feats.clip_id)
        self.save(ctx.out_dir / "index")
        segs, lists = [], []
        for name, s in self.sets.items():
            t = s.segments_table()
            segs.append(t.add_column(0, "feature_set", pa.array([name] * t.num_rows, pa.string())))
            lt = s.lists_table()
            lists.append(lt.add_column(0, "feature_set", pa.array([name] * lt.num_rows, pa.string())))
        summary = {
            n: {"segments": s.n_segments, "lists": len(s.list_codes), "bytes": s.nbytes()} for n, s in self.sets.items()
        }
        return StepOutput({"data": pa.concat_tables(segs), "lists": pa.concat_tables(lists)}, summary)


__all__ = ["InvertedIndex", "SetIndex"]
