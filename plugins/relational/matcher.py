"""Content-based retrieval with relational features (Müller, Röder, Clausen 2005, §5-§7).

Queries
-------
by example
    A clip (or a frame range of it) and a subset S of the 31 features. For each feature
    set touched by S the query's S-segmentation gives the sequence ``v_1 .. v_L``; the
    alternatives of ``v_l`` are every code of the set that agrees with ``v_l`` on S
    (``V_l = {c : c & mask == v_l}``). Selections spanning several sets are answered by
    querying each set's index and intersecting the hits (same clip, frame spans
    overlapping by ``min_overlap`` of the shorter one).
scene description (§6.3)
    Progressions of constellations (``{feature: 0/1}`` per step, omitted features are
    "*"), each answered by an adaptive fuzzy query, combined under co-occurrence
    constraints ``(progression a, step i, progression b, step j)``: those steps overlap.

Modes
-----
``exact`` (eq. 7, the selection must cover whole feature sets), ``fuzzy`` (eq. 11, the
database segmentation is kept), ``adaptive`` (§5.2, the database segmentation is coarsened
to maximal runs of each ``V_l``: exact hits for the selected features; the default) and
``mismatch`` (up to ``mismatches`` levels may disagree, optionally only at
``mismatch_positions``, on the coarsened segmentation; dynamic programming kernel).

Ranking and refinement
----------------------
Hits are ranked by the segment-length heuristic of §6.2: ``cost = sum_l |len_Q(l) -
len_D(l)| / len(Q)`` (frames). With ``refine`` a DTW on root-relative joint positions is run
inside the band of matched segments widened by ``margin`` frames (§7); the warping path
(query frame, database frame), both within their clips, goes to the ``path`` column and
the DTW cost per path step to ``dtw_cost``.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np
import pyarrow as pa
from pydantic import Field

from mocapflow.framework.components import Matcher, Params
from mocapflow.framework.errors import ConfigError, PipelineError
from mocapflow.framework.schema import MATCHES, WARPING_PATH
from .features import FEATURE_IDS, SET_SLICES, feature_column, feature_set_of
from .segmentation import segment
from .inverted import InvertedIndex, SetIndex

if TYPE_CHECKING:  # pragma: no cover
    from mocapflow.framework.context import StepContext
    from mocapflow.framework.datasets import Dataset, StepOutput

Mode = Literal["exact", "fuzzy", "adaptive", "mismatch"]
#: Modes of a query by example: the paper's four plus ``auto`` (features chosen automatically).
ExampleMode = Literal["auto", "exact", "fuzzy", "adaptive", "mismatch"]


@dataclass
class Hits:
    """Hits of one query: global frame spans, ranking cost and per-level correspondences.

    ``levels`` (n, L, 2) global database frame ranges of the query levels and
    ``query_levels`` (L, 2) query frame ranges, for single-set hits (DTW refinement).
    """

    clip: np.ndarray
    start: np.ndarray
    end: np.ndarray
    cost: np.ndarray
    levels: np.ndarray | None = None
    query_levels: np.ndarray | None = None
    sets: str = ""
    n_levels: int = 0
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.start)

    @classmethod
    def empty(cls, sets: str = "") -> Hits:
        z = np.zeros(0, np.int64)
        return cls(z, z, z, np.zeros(0), sets=sets)


def coarsen_fuzzy(member: np.ndarray) -> np.ndarray:
    """Merge adjacent fuzzy sets that intersect until neighbours are disjoint (§5.2)."""
    rows: list[np.ndarray] = []
    for row in np.asarray(member, dtype=bool):
        rows.append(row.copy())
        # a merged set may now meet the set before it: keep conjoining backwards
        while len(rows) > 1 and np.any(rows[-2] & rows[-1]):
            last = rows.pop()
            rows[-1] = rows[-1] | last
    return np.array(rows, dtype=bool).reshape(-1, np.asarray(member).shape[-1])


def subset_member(values: np.ndarray, mask: int, n_bits: int) -> np.ndarray:
    """Fuzzy sets ``V_l = {c : c & mask == values[l]}`` as a (L, 2**n_bits) boolean table."""
    codes = np.arange(1 << n_bits, dtype=np.int64)
    return (codes[None, :] & mask) == np.asarray(values, np.int64)[:, None]


def _level_frames(idx: SetIndex, bounds: np.ndarray) -> np.ndarray:
    """Global frame ranges (n, L, 2) of hits given segment bounds (n, L+1)."""
    return np.stack([idx.seg_start[bounds[:, :-1]], idx.seg_end[bounds[:, 1:] - 1]], axis=-1)


def search_set(idx: SetIndex, member: np.ndarray, mode: Mode, mismatches: int = 1,
               allowed: np.ndarray | None = None, mask: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Hits of one fuzzy query in one set index.

    ``member`` (L, 2**f) holds the fuzzy sets; ``mask`` the bits they constrain (derived
    from ``member`` when omitted), used by ``mismatch`` to coarsen the database.

    Returns
    -------
    levels : ndarray of int64, shape (n, L, 2)
        Global database frame range of each query level per hit.
    n_mismatch : ndarray of int64, shape (n,)
    """
    n_levels = len(member)
    if mode not in ("exact", "fuzzy", "adaptive", "mismatch"):
        raise ConfigError(f"unknown relational matching mode {mode!r}; choose exact, fuzzy, adaptive or mismatch")
    if mode == "adaptive":
        bounds = idx.adaptive(coarsen_fuzzy(member)) if n_levels else np.zeros((0, 1), np.int64)
        return _level_frames(idx, bounds), np.zeros(len(bounds), np.int64)
    if mode in ("exact", "fuzzy"):
        if mode == "exact":
            codes = member.argmax(axis=1)
            starts = idx.exact(codes)
        else:
            starts = idx.fuzzy(member)
        bounds = starts[:, None] + np.arange(n_levels + 1)[None, :]
        return _level_frames(idx, bounds), np.zeros(len(starts), np.int64)
    # mismatch: on the segmentation coarsened to the query's features (projected codes)
    from ._match_kernels import mismatch_scan

    proj = idx.seg_code & (_query_mask(member) if mask is None else mask)
    brk = np.r_[True, proj[1:] != proj[:-1]] | idx.clip_first
    first_seg = np.flatnonzero(brk)
    end_seg = np.append(first_seg[1:], idx.n_segments)
    allowed = np.ones(n_levels, bool) if allowed is None else np.asarray(allowed, bool)
    starts, bad = mismatch_scan(proj[first_seg], idx.seg_clip[first_seg], np.ascontiguousarray(member),
                                allowed, int(mismatches))
    bounds = np.concatenate([first_seg[starts[:, None] + np.arange(n_levels)[None, :]],
                             end_seg[starts + n_levels - 1][:, None]], axis=1) if len(starts) else np.zeros((0, n_levels + 1), np.int64)
    return _level_frames(idx, bounds), bad


def _query_mask(member: np.ndarray) -> int:
    """The bits a fuzzy table constrains (bits whose flip changes membership somewhere)."""
    n_bits = int(np.log2(member.shape[1]))
    codes = np.arange(member.shape[1])
    mask = 0
    for b in range(n_bits):
        if np.any(member[:, codes] != member[:, codes ^ (1 << b)]):
            mask |= 1 << b
    return mask


def example_query(index: InvertedIndex, bits: np.ndarray, columns: list[int], mode: Mode = "adaptive",
                  mismatches: int = 1, mismatch_positions: tuple[int, ...] | None = None,
                  min_overlap: float = 0.5) -> Hits:
    """Query by example: the query clip's boolean features and a selection of columns.

    Parameters
    ----------
    index : InvertedIndex
    bits : ndarray of shape (T_q, 31), bool or 0/1
        Features of the query frames.
    columns : list of int
        Selected feature columns (0..30).
    mismatch_positions : tuple of int, optional
        Query levels (0-based, per set) where ``mismatch`` mode may accept a mismatch.
    """
    parts = []
    for name, sl in SET_SLICES.items():
        cols = [c for c in columns if sl.start <= c < sl.stop]
        if not cols:
            continue
        if name not in index.sets:
            raise ConfigError(f"matchers.relational: the index has no {name!r} set (features {cols})")
        idx = index.sets[name]
        local = [c - sl.start for c in cols]
        if mode == "exact" and len(local) != idx.n_features:
            raise ConfigError(f"mode 'exact' compares whole feature sets; select all of {name!r} or use mode 'adaptive'")
        seg = segment(bits, cols)
        # re-express the segment codes in the set's own bit positions
        values = np.zeros(len(seg), np.int64)
        for i, b in enumerate(local):
            values |= ((seg.code >> i) & 1) << b
        mask = sum(1 << b for b in local)
        member = subset_member(values, mask, idx.n_features)
        qlev = np.stack([seg.start, seg.end], axis=1)
        allowed = None if mismatch_positions is None else np.isin(np.arange(len(seg)), mismatch_positions)
        levels, bad = search_set(idx, member, mode, mismatches, allowed, mask)
        dlen = levels[:, :, 1] - levels[:, :, 0]
        qlen = qlev[:, 1] - qlev[:, 0]
        cost = np.abs(dlen - qlen[None, :]).sum(axis=1) / max(int(qlen.sum()), 1)
        clip = np.searchsorted(idx.clip_offsets, levels[:, 0, 0], side="right") - 1
        h = Hits(clip.astype(np.int64), levels[:, 0, 0], levels[:, -1, 1], cost.astype(np.float64), levels, qlev, name, len(seg),
                 {"mismatches": bad})
        parts.append(h)
    if not parts:
        raise ConfigError("matchers.relational: a query needs at least one feature")
    out = parts[0]
    for other in parts[1:]:
        out = combine(out, other, min_overlap)
    return out


def combine(a: Hits, b: Hits, min_overlap: float = 0.5) -> Hits:
    """Hits of two indexes that co-occur: same clip, spans overlapping by ``min_overlap``
    of the shorter span. The result spans the union; its cost is the mean; per-level
    correspondences of the part with more levels are kept for refinement."""
    ia, ib = [], []
    for c in np.intersect1d(a.clip, b.clip):
        xa, xb = np.flatnonzero(a.clip == c), np.flatnonzero(b.clip == c)
        ov = np.minimum(a.end[xa, None], b.end[None, xb]) - np.maximum(a.start[xa, None], b.start[None, xb])
        shorter = np.minimum((a.end - a.start)[xa, None], (b.end - b.start)[None, xb])
        r, s = np.nonzero(ov >= np.maximum(min_overlap * shorter, 1))
        ia.append(xa[r])
        ib.append(xb[s])
    ia = np.concatenate(ia) if ia else np.zeros(0, np.int64)
    ib = np.concatenate(ib) if ib else np.zeros(0, np.int64)
    keep, kidx = (a, ia) if a.n_levels >= b.n_levels else (b, ib)
    return Hits(a.clip[ia], np.minimum(a.start[ia], b.start[ib]), np.maximum(a.end[ia], b.end[ib]),
                0.5 * (a.cost[ia] + b.cost[ib]), None if keep.levels is None else keep.levels[kidx],
                keep.query_levels, f"{a.sets}+{b.sets}", keep.n_levels,
                {"mismatches": a.extra.get("mismatches", np.zeros(len(a), np.int64))[ia]
                 + b.extra.get("mismatches", np.zeros(len(b), np.int64))[ib]})


def scene_query(index: InvertedIndex, progressions: list[list[dict[str, int]]],
                overlaps: list[tuple[int, int, int, int]] = ()) -> Hits:
    """Geometric scene description (§6.3): progressions combined under co-occurrence.

    Parameters
    ----------
    progressions : list of lists of ``{feature: 0 or 1}``
        Each progression is a sequence of constellations over features of one set; a
        feature left out of a step is unspecified ("*"), and steps whose alternatives
        intersect are merged (§5.2).
    overlaps : list of ``(a, i, b, j)``
        Step ``i`` of progression ``a`` must overlap in time with step ``j`` of ``b``.
    """
    per: list[Hits] = []
    for p, prog in enumerate(progressions):
        cols = [[feature_column(k) for k in step] for step in prog]
        sets = {feature_set_of(c) for step in cols for c in step}
        if len(sets) != 1:
            raise ConfigError(f"scene progression {p} must use features of exactly one set, got {sorted(sets) or 'none'}; "
                              "split it into progressions linked by overlaps")
        name = sets.pop()
        idx = index.sets[name]
        base = SET_SLICES[name].start
        member = np.ones((len(prog), 1 << idx.n_features), bool)
        for row, (step, scols) in enumerate(zip(prog, cols)):
            for (k, v), c in zip(step.items(), scols):
                member[row] &= subset_member(np.array([int(v) << (c - base)]), 1 << (c - base), idx.n_features)[0]
        if len(coarsen_fuzzy(member)) != len(member):
            raise ConfigError(f"scene progression {p}: adjacent steps must differ in a specified feature")
        levels, _ = search_set(idx, member, "adaptive")
        clip = np.searchsorted(idx.clip_offsets, levels[:, 0, 0], side="right") - 1
        per.append(Hits(clip.astype(np.int64), levels[:, 0, 0], levels[:, -1, 1], np.zeros(len(levels)),
                        levels, None, name, len(member)))
    if not per:
        raise ConfigError("a scene description needs at least one progression")
    # join progressions one by one; combos[k] holds hit indices into per[k]
    combos = [np.arange(len(per[0]))]
    for b in range(1, len(per)):
        cons = [(a, i, j) for a, i, bb, j in overlaps if bb == b and a < b] + \
               [(bb, j, i) for bb, j, a, i in overlaps if a == b and bb < b]
        new_a, new_b = [], []
        hb = per[b]
        for c in np.unique(per[0].clip[combos[0]]):
            ra = np.flatnonzero(per[0].clip[combos[0]] == c)
            rb = np.flatnonzero(hb.clip == c)
            ok = np.ones((len(ra), len(rb)), bool)
            for a, i, j in cons:
                la = per[a].levels[combos[a][ra], i]
                lb = hb.levels[rb, j]
                ok &= np.minimum(la[:, None, 1], lb[None, :, 1]) > np.maximum(la[:, None, 0], lb[None, :, 0])
            r, q = np.nonzero(ok)
            new_a.append(ra[r])
            new_b.append(rb[q])
        sel = np.concatenate(new_a) if new_a else np.zeros(0, np.int64)
        combos = [x[sel] for x in combos] + [np.concatenate(new_b) if new_b else np.zeros(0, np.int64)]
    start = np.min([per[k].start[combos[k]] for k in range(len(per))], axis=0)
    end = np.max([per[k].end[combos[k]] for k in range(len(per))], axis=0)
    return Hits(per[0].clip[combos[0]], start, end, np.zeros(len(start)), sets="+".join(h.sets for h in per),
                n_levels=sum(h.n_levels for h in per))


def dtw_band(query_levels: np.ndarray, levels: np.ndarray, margin: int) -> tuple[np.ndarray, np.ndarray]:
    """Per query row the admissible database columns ``[lo, hi)`` around matched segments (§7).

    Parameters
    ----------
    query_levels : ndarray (L, 2)
        Query frame range per level, relative to the query's first frame.
    levels : ndarray (L, 2)
        Database frame range per level, relative to the hit's first frame.
    margin : int
        Frames by which each rectangle is enlarged in both directions.
    """
    n, m = int(query_levels[-1, 1]), int(levels[-1, 1])
    lo = np.full(n, m, np.int64)
    hi = np.zeros(n, np.int64)
    for (qs, qe), (ds, de) in zip(query_levels, levels):
        rows = slice(max(qs - margin, 0), min(qe + margin, n))
        lo[rows] = np.minimum(lo[rows], max(ds - margin, 0))
        hi[rows] = np.maximum(hi[rows], min(de + margin, m))
    return lo, hi


def refine(query_pose: np.ndarray, db_pose: np.ndarray, query_levels: np.ndarray, levels: np.ndarray,
           margin: int) -> tuple[float, np.ndarray, int]:
    """DTW inside the band of matched segments; returns (cost per step, path (P, 2), cells)."""
    from ._match_kernels import banded_dtw

    q0, d0 = query_levels[0, 0], levels[0, 0]
    lo, hi = dtw_band(query_levels - q0, levels - d0, margin)
    cost, path, cells = banded_dtw(query_pose, db_pose, lo, hi)
    return float(cost) / max(len(path), 1), path, int(cells)


def pose_features(positions: np.ndarray) -> np.ndarray:
    """Root-relative, heading-normalised joint positions (T, 75) for DTW (NaN -> 0)."""
    from mocapflow.framework.normalize import to_root_frame

    p = to_root_frame(positions).reshape(len(positions), -1)
    return np.nan_to_num(p).astype(np.float64)


class ExampleQuery(Params):
    """A query by example: a clip (name or clip id), a frame range and a feature selection."""

    clip: str | int = Field(description="clip name (needs the 'motions' input) or clip id in the query dataset")
    start_frame: int = Field(0, ge=0, description="first query frame")
    end_frame: int | None = Field(None, description="end of the query frames (exclusive); default the clip's end")
    features: tuple[str, ...] = Field((), description="selected features: ids (L3, U1, M7) or names (rfoot_raised); "
                                      "in mode auto the features the selection may choose from (default all)")
    examples: tuple[str | int, ...] = Field((), description="mode auto: further example clips (names or ids) of the same motion")


class SceneQuery(Params):
    """A geometric scene description (§6.3)."""

    progressions: tuple[tuple[dict[str, int], ...], ...] = Field(min_length=1, description="per progression, steps {feature: 0/1}")
    overlaps: tuple[tuple[int, int, int, int], ...] = Field((), description="(a, i, b, j): step i of progression a overlaps step j of b")


class RelationalMatcher(Matcher):
    """Retrieval over ``indexes.inverted`` by example or by scene description (Müller et al. 2005).

    Inputs: ``database`` (an ``indexes.inverted`` dataset), ``query`` (a
    ``features.relational`` dataset holding the query clips) and optionally ``motions``
    (the motions dataset behind both, for clip names and DTW refinement). Output: the
    shared match table plus ``mode``, ``feature_sets``, ``n_segments``, ``mismatches``,
    ``dtw_cost`` and, with ``refine``, ``path``.
    """

    name = "relational"
    version = "2"
    inputs = {"database": True, "query": True, "motions": False}
    #: Conformance (mocapflow.framework.testing): a query by example on synthetic clips.
    test_pipeline = {
        "steps": {"feat": {"uses": "features.relational", "input": "motions"},
                  "inv": {"uses": "indexes.inverted", "input": "feat"}},
        "inputs": {"database": "inv", "query": "feat", "motions": "motions"},
        "with": {"queries": [{"clip": "synthetic2", "start_frame": 10, "end_frame": 50}]},
        "bad_inputs": {"database": "feat", "query": "feat", "motions": "motions"},
    }

    class Params(Params):
        queries: tuple[ExampleQuery, ...] = Field((), description="queries by example")
        scenes: tuple[SceneQuery, ...] = Field((), description="scene descriptions (query ids follow the example queries)")
        mode: ExampleMode = Field("auto", description="auto (features chosen from the example), exact (eq. 7), fuzzy (eq. 11), "
                                  "adaptive (§5.2) or mismatch")
        auto_search: Literal["dtw", "adaptive", "mismatch"] = Field("dtw", description="mode auto: subsequence DTW of the "
                                                                    "example as a template, or the paper's adaptive / mismatch hits")
        min_run: int = Field(4, ge=1, description="mode auto: runs shorter than this (frames) are flicker")
        max_features: int = Field(3, ge=1, le=31, description="mode auto with adaptive/mismatch search: features selected")
        relative_cut: float | None = Field(None, gt=0.0, description="mode auto, dtw: hits cost below this x q^w x "
                                           "median^(1-w) of the database's per-clip least costs (q: their 5 % quantile, "
                                           "w: low_weight); default 1.3 for hits the mutual check passes, 1.15 for "
                                           "unchecked ones (auto_mutual off, or long clips under auto)")
        low_weight: float = Field(0.75, ge=0.0, le=1.0, description="mode auto, dtw: weight w of the low quantile in the cut "
                                  "(0: relative_cut x the median, the first design)")
        max_cost: float | None = Field(None, gt=0.0, description="mode auto, dtw: fixed cost cut instead of relative_cut")
        auto_features: Literal["all", "key"] = Field("all", description="mode auto, dtw: the example template on all 31 "
                                                     "features or on its key features (the first design)")
        auto_mutual: Literal["auto", "clip", "off"] = Field("auto", description="mode auto, dtw: reverse check of each "
                                                            "hit (the hit's clip as a query must find the query clip too): "
                                                            "clip on every hit (databases of cut motions), auto only where "
                                                            "the hit's clip is at most mutual_ratio x the query's length, for an example that is a whole clip "
                                                            "(long takes: mutual_window or no check), off; docs/templates.md")
        mutual_ratio: float = Field(3.0, gt=0.0, description="mode auto, auto_mutual auto: a hit's clip of at most this "
                                    "x the query's frames is checked as a whole")
        mutual_window: float | None = Field(None, ge=0.0, description="mode auto, auto_mutual auto: in a longer clip "
                                            "the reverse query is a window of the query's length x (1 + this) around "
                                            "the hit; None: such hits are not checked (and get the plain cut)")
        mutual_sample: int | None = Field(256, ge=8, description="mode auto, mutual check: the reverse search covers a "
                                          "fixed random sample of this many clips (its cut needs only the quantiles "
                                          "of their costs); None: every clip")
        auto_weighting: float = Field(0.5, ge=0.0, le=4.0, description="mode auto, dtw: a mismatch costs the surprise of the "
                                      "example's value under the database's on-fraction, to this power (0: unweighted)")
        mismatches: int = Field(1, ge=0, description="m of m-mismatch hits")
        mismatch_positions: tuple[int, ...] | None = Field(None, description="query levels (0-based) where mismatches may occur; default any")
        min_overlap: float = Field(0.5, ge=0.0, le=1.0, description="overlap (fraction of the shorter span) for combining hits of several indexes")
        max_hits: int | None = Field(None, ge=1, description="keep the best max_hits per query")
        refine: bool = Field(False, description="DTW refinement of the coarse alignment (§7); needs 'motions'")
        margin: int = Field(4, ge=0, description="frames by which matched segments are enlarged for DTW (§7)")

    def search(self, index: InvertedIndex, bits: np.ndarray, features: tuple[str, ...]) -> Hits:
        """Hits of one query by example (features of the query frames, shape (T, 31))."""
        cols = sorted({feature_column(f) for f in features})
        return example_query(index, bits, cols, self.params.mode, self.params.mismatches,
                             self.params.mismatch_positions, self.params.min_overlap)

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        from mocapflow.framework.datasets import StepOutput

        db_ds, q_ds = inputs["database"], inputs["query"]
        if db_ds.producer != "indexes.inverted" or q_ds.producer != "features.relational":
            raise PipelineError(f"matchers.relational needs database=indexes.inverted and query=features.relational, "
                                f"got {db_ds.producer} and {q_ds.producer}")
        index = InvertedIndex.load(db_ds.path / "index")
        q = q_ds.features()
        names: dict[str, int] = {}
        mdb = None
        if "motions" in inputs:
            clips = inputs["motions"].table("clips", columns=["clip_id", "name"])
            names = dict(zip(clips["name"].to_pylist(), clips["clip_id"].to_pylist()))
            if self.params.refine:
                mdb = inputs["motions"].motions()
        elif self.params.refine:
            raise ConfigError("matchers.relational: refine needs the 'motions' input")
        rows: list[dict] = []
        for qid, spec in enumerate(self.params.queries):
            cid = spec.clip if isinstance(spec.clip, int) else names.get(spec.clip)
            if cid is None:
                raise ConfigError(f"query {qid}: unknown clip {spec.clip!r}" + ("" if names else " (give 'motions' to use names)"))
            sel = (q.clip_id == cid) & (q.frame >= spec.start_frame)
            if spec.end_frame is not None:
                sel &= q.frame < spec.end_frame
            if not sel.any():
                raise ConfigError(f"query {qid}: no frames of clip {spec.clip!r} in the query dataset")
            if self.params.mode == "auto":
                exs = [q.x[q.clip_id == self._clip_id(e, names, qid)] for e in spec.examples]
                # the reverse check compares clip with clip: it presumes the example is a whole cut
                whole = int(sel.sum()) >= 0.8 * int((q.clip_id == cid).sum())
                rows += self._auto_rows(qid, index, q.x[sel], spec, exs, whole)
                continue
            if not spec.features:
                raise ConfigError(f"query {qid}: mode {self.params.mode!r} needs 'features' (or use mode auto)")
            hits = self.search(index, q.x[sel], spec.features)
            qpos = q.frame[sel][0]
            ids = ",".join(FEATURE_IDS[c] for c in sorted({feature_column(f) for f in spec.features}))
            rows += [{**r, "features": ids} for r in self._rows(qid, index, hits, mdb, (int(cid), int(qpos)))]
        for sid, scene in enumerate(self.params.scenes):
            hits = scene_query(index, [list(p) for p in scene.progressions], [tuple(o) for o in scene.overlaps])
            ids = ",".join(FEATURE_IDS[c] for c in sorted({feature_column(k) for p in scene.progressions for st in p for k in st}))
            rows += [{**r, "features": ids} for r in self._rows(len(self.params.queries) + sid, index, hits, None, None)]
        return StepOutput({"data": hits_table(rows, self.params.refine)},
                          {"queries": len(self.params.queries) + len(self.params.scenes), "hits": len(rows)})

    @staticmethod
    def _clip_id(clip: str | int, names: dict[str, int], qid: int) -> int:
        cid = clip if isinstance(clip, int) else names.get(clip)
        if cid is None:
            raise ConfigError(f"query {qid}: unknown example clip {clip!r}" + ("" if names else " (give 'motions' to use names)"))
        return int(cid)

    def _auto_rows(self, qid: int, index: InvertedIndex, bits: np.ndarray, spec: ExampleQuery,
                   examples: list[np.ndarray], whole: bool = True) -> list[dict]:
        """Mode auto: features selected from the example, then DTW or the paper's machinery.
        ``whole``: the example covers (at least 80 % of) its clip; ``auto_mutual: auto`` checks
        hits only then, since a piece of a take is no cut whose clip could be compared with
        the hit's clip (``clip`` checks regardless)."""
        from .auto import auto_dtw_hits, auto_template, select_features
        from .template_model import frame_codes

        cache = getattr(self, "_frames", None)
        if cache is None or cache[0] is not index:
            db_bits = index.frame_bits()
            any_set = next(iter(index.sets.values()))
            cache = (index, frame_codes(db_bits), db_bits.mean(axis=0) if len(db_bits) else np.zeros(31), any_set, db_bits)
            self._frames = cache
        _, codes, background, any_set, db_bits = cache
        allowed = sorted({feature_column(f) for f in spec.features}) if spec.features else None
        if self.params.auto_search == "dtw":
            t = auto_template(bits, background, examples, self.params.min_run, self.params.auto_features,
                              self.params.auto_weighting)
            if allowed is not None:
                keep = np.intersect1d(t.columns, allowed)
                t.columns = keep if len(keep) else np.asarray(allowed, np.int64)
            pr = self.params
            mutual = "off" if pr.auto_mutual == "auto" and not whole else pr.auto_mutual
            s, e, c = auto_dtw_hits(t, bits, db_bits, codes, any_set.clip_offsets, background, mutual,
                                    pr.relative_cut, pr.max_cost, pr.low_weight, pr.mutual_ratio, pr.mutual_window,
                                    pr.min_run, pr.auto_features, pr.auto_weighting, pr.mutual_sample)
            used = t.columns
            hits = Hits(np.searchsorted(any_set.clip_offsets, s, side="right") - 1, s, e, c,
                        sets="+".join(sorted({feature_set_of(int(x)) for x in used})), n_levels=t.n_frames)
        else:
            used, sm, _ = select_features(bits, background, examples, self.params.min_run, max_features=self.params.max_features,
                                          allowed=allowed)
            if not len(used):
                return []
            mode = self.params.auto_search
            hits = example_query(index, sm, sorted(int(x) for x in used), mode, self.params.mismatches,
                                 self.params.mismatch_positions, self.params.min_overlap)
        rows = self._rows(qid, index, hits, None, None)
        ids = ",".join(FEATURE_IDS[int(x)] for x in sorted(used))
        for r in rows:
            r.update(mode="auto", features=ids)
            if self.params.auto_search == "dtw":
                r["dtw_cost"] = r["cost"]
        return rows

    def _rows(self, qid: int, index: InvertedIndex, hits: Hits, mdb, query_clip) -> list[dict]:
        any_set = next(iter(index.sets.values()))
        order = np.lexsort((hits.start, hits.clip, hits.cost))
        # several combinations (scene progressions, combined indexes) can give one span: keep the best
        if len(order):
            spans = np.stack([hits.clip[order], hits.start[order], hits.end[order]])
            order = order[np.sort(np.unique(spans, axis=1, return_index=True)[1])]
        if self.params.max_hits:
            order = order[: self.params.max_hits]
        out = []
        for rank, h in enumerate(order, start=1):  # ranks are 1-based in every match table
            pos = int(hits.clip[h])
            first = int(any_set.clip_offsets[pos])
            row = {"query_id": qid, "rank": rank, "clip_id": int(any_set.clip_ids[pos]),
                   "start_frame": int(hits.start[h] - first), "end_frame": int(hits.end[h] - first),
                   "cost": float(hits.cost[h]), "mode": self.params.mode if query_clip else "scene",
                   "feature_sets": hits.sets, "n_segments": hits.n_levels,
                   "mismatches": int(hits.extra.get("mismatches", np.zeros(len(hits), np.int64))[h]),
                   "dtw_cost": None, "path": None, "features": hits.sets}
            if mdb is not None and query_clip is not None and hits.levels is not None:
                row.update(self._refine(mdb, query_clip, pos, hits.levels[h] - first, hits.query_levels, index))
            out.append(row)
        return out

    def _refine(self, mdb, query_clip, pos, levels, query_levels, index) -> dict:
        any_set = next(iter(index.sets.values()))
        where = {int(c): i for i, c in enumerate(mdb.clip_ids)}
        qm = mdb.motions[where[query_clip[0]]]
        dm = mdb.motions[where[int(any_set.clip_ids[pos])]]
        ql = query_levels + query_clip[1]
        qa = pose_features(qm.canonical_positions()[ql[0, 0]:ql[-1, 1]])
        da = pose_features(dm.canonical_positions()[levels[0, 0]:levels[-1, 1]])
        cost, path, _ = refine(qa, da, ql, levels, self.params.margin)
        path = path + np.array([ql[0, 0], levels[0, 0]])
        return {"dtw_cost": cost if np.isfinite(cost) else None, "path": path.tolist()}


def hits_table(rows: list[dict], with_path: bool = False) -> pa.Table:
    """Rows -> a match table (:data:`~mocapflow.framework.schema.MATCHES` + relational columns)."""
    fields = list(MATCHES) + [pa.field("mode", pa.string()), pa.field("feature_sets", pa.string()),
                              pa.field("n_segments", pa.int32()), pa.field("mismatches", pa.int32()),
                              pa.field("dtw_cost", pa.float64()), pa.field("features", pa.string())]
    if with_path:
        fields.append(WARPING_PATH)
    schema = pa.schema(fields)
    return pa.table({f.name: pa.array([r[f.name] for r in rows], f.type) for f in schema}, schema=schema)


__all__ = ["ExampleQuery", "Hits", "RelationalMatcher", "SceneQuery", "hits_table", "coarsen_fuzzy", "combine", "dtw_band", "example_query", "pose_features", "refine", "scene_query",
           "search_set", "subset_member"]
