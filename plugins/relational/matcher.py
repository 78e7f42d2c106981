"""Content-based retrieval with relational features (Müller, Röder, Clausen 2005, §5-§7).

The query algorithms (by example, scene description, the four modes) are in
``queries.py``; this module ranks and refines their hits and is the ``matchers.relational``
component.

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
from typing import TYPE_CHECKING, Any, Literal, cast

import numpy as np
import pyarrow as pa
from pydantic import Field

from mocapflow.framework.components import Matcher, Params
from mocapflow.framework.components import Params as BaseParams
from mocapflow.framework.errors import ConfigError, PipelineError
from mocapflow.framework.schema import MATCHES, WARPING_PATH

from .feature_table import FEATURE_IDS, feature_column, feature_set_of
from .inverted import InvertedIndex
from .queries import Hits, example_query, scene_query

if TYPE_CHECKING:  # pragma: no cover
    from mocapflow.framework.context import StepContext
    from mocapflow.framework.datasets import Dataset, StepOutput

#: Modes of a query by example: the paper's four plus ``auto`` (features chosen automatically).
ExampleMode = Literal["auto", "exact", "fuzzy", "adaptive", "mismatch"]


def dtw_band(query_levels: np.ndarray, levels: np.ndarray, margin: int) -> tuple[np.ndarray, np.ndarray]:
    """Per query row the admissible database columns ``[lo, hi)`` around matched segments (§7).

    ``query_levels`` (L, 2): query frame range per level, from the query's first frame;
    ``levels`` (L, 2): database frame range per level, from the hit's first frame; each
    rectangle is enlarged by ``margin`` frames in both directions.
    """
    n, m = int(query_levels[-1, 1]), int(levels[-1, 1])
    lo = np.full(n, m, np.int64)
    hi = np.zeros(n, np.int64)
    for (qs, qe), (ds, de) in zip(query_levels, levels, strict=True):
        rows = slice(max(qs - margin, 0), min(qe + margin, n))
        lo[rows] = np.minimum(lo[rows], max(ds - margin, 0))
        hi[rows] = np.maximum(hi[rows], min(de + margin, m))
    return lo, hi


def refine(
    query_pose: np.ndarray, db_pose: np.ndarray, query_levels: np.ndarray, levels: np.ndarray, margin: int
) -> tuple[float, np.ndarray, int]:
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
    return cast("np.ndarray", np.nan_to_num(p).astype(np.float64))


class ExampleQuery(Params):
    """A query by example: a clip (name or clip id), a frame range and a feature selection."""

    clip: str | int = Field(description="clip name (needs the 'motions' input) or clip id in the query dataset")
    start_frame: int = Field(0, ge=0, description="first query frame")
    end_frame: int | None = Field(None, description="end of the query frames (exclusive); default the clip's end")
    features: tuple[str, ...] = Field(
        (),
        description="selected features: ids (L3, U1, M7) or names (rfoot_raised); "
        "in mode auto the features the selection may choose from (default all)",
    )
    examples: tuple[str | int, ...] = Field(
        (), description="mode auto: further example clips (names or ids) of the same motion"
    )


class SceneQuery(Params):
    """A geometric scene description (§6.3)."""

    progressions: tuple[tuple[dict[str, int], ...], ...] = Field(
        min_length=1, description="per progression, steps {feature: 0/1}"
    )
    overlaps: tuple[tuple[int, int, int, int], ...] = Field(
        (), description="(a, i, b, j): step i of progression a overlaps step j of b"
    )


class RelationalMatcher(Matcher):
    """Retrieval over ``indexes.inverted`` by example or by scene description (Müller et al. 2005).

    Inputs: ``database`` (an ``indexes.inverted`` dataset), ``query`` (a
    ``features.relational`` dataset holding the query clips) and optionally ``motions``
    (the motions dataset behind both, for clip names and DTW refinement) and ``numeric`` (a
    matcher step such as ``matchers.search`` run with the same queries in the same order:
    mode auto keeps only hits its per-clip costs support, ``fusion``). Output: the
    shared match table plus ``mode``, ``feature_sets``, ``n_segments``, ``mismatches``,
    ``dtw_cost`` and, with ``refine``, ``path``.
    """

    name = "relational"
    version = "3"
    inputs = {"database": True, "query": True, "motions": False, "numeric": False}
    #: Conformance (mocapflow.framework.testing): a query by example on synthetic clips.
    test_pipeline = {
        "steps": {
            "feat": {"uses": "features.relational", "input": "motions"},
            "inv": {"uses": "indexes.inverted", "input": "feat"},
        },
        "inputs": {"database": "inv", "query": "feat", "motions": "motions"},
        "with": {"queries": [{"clip": "synthetic2", "start_frame": 10, "end_frame": 50}]},
        "bad_inputs": {"database": "feat", "query": "feat", "motions": "motions"},
    }

    class Params(BaseParams):
        queries: tuple[ExampleQuery, ...] = Field((), description="queries by example")
        scenes: tuple[SceneQuery, ...] = Field(
            (), description="scene descriptions (query ids follow the example queries)"
        )
        mode: ExampleMode = Field(
            "auto",
            description="auto (features chosen from the example), exact (eq. 7), fuzzy (eq. 11), "
            "adaptive (§5.2) or mismatch",
        )
        relative_cut: float | None = Field(
            None,
            gt=0.0,
            description="mode auto: hits cost below this x q^0.75 x "
            "median^0.25 of the database's per-clip least costs (q: their 5 % quantile); "
            "default 1.3 for hits the mutual check passes, 1.15 for unchecked ones",
        )
        auto_mutual: Literal["auto", "clip", "off"] = Field(
            "auto",
            description="mode auto: reverse check of each "
            "hit (the hit's clip as a query must find the query clip "
            "too): auto only where the hit's clip is at most "
            "mutual_ratio x the query's length, for an example that is "
            "a whole clip; clip on every hit (databases of cut motions); "
            "off; docs/templates.md",
        )
        mutual_ratio: float = Field(
            3.0,
            gt=0.0,
            description="mode auto, auto_mutual auto: a hit's clip of at most this "
            "x the query's frames is checked as a whole",
        )
        mismatches: int = Field(1, ge=0, description="m of m-mismatch hits")
        mismatch_positions: tuple[int, ...] | None = Field(
            None, description="query levels (0-based) where mismatches may occur; default any"
        )
        min_overlap: float = Field(
            0.5,
            ge=0.0,
            le=1.0,
            description="overlap (fraction of the shorter span) for combining hits of several indexes",
        )
        max_hits: int | None = Field(None, ge=1, description="keep the best max_hits per query")
        refine: bool = Field(False, description="DTW refinement of the coarse alignment (§7); needs 'motions'")
        margin: int = Field(4, ge=0, description="frames by which matched segments are enlarged for DTW (§7)")
        fusion: float | None = Field(
            1.6,
            gt=0.0,
            description="mode auto with a 'numeric' input (a matcher step, e.g. matchers.search, with the same "
            "queries in the same order and count >= the database's clips): keep a hit only if the numeric "
            "search's cost of its clip is <= fusion x the auto cut's blend of those costs; None: off "
            "(docs/templates.md: chosen by nested leave-one-actor-out)",
        )

    params: Params

    def search(self, index: InvertedIndex, bits: np.ndarray, features: tuple[str, ...]) -> Hits:
        """Hits of one query by example (features of the query frames, shape (T, 31))."""
        cols = sorted({feature_column(f) for f in features})
        mode = self.params.mode
        if mode == "auto":
            raise ConfigError(
                f"{self.key()}: search() runs one feature selection; mode auto chooses its own (run the step)"
            )
        return example_query(
            index,
            bits,
            cols,
            mode,
            self.params.mismatches,
            self.params.mismatch_positions,
            self.params.min_overlap,
        )

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        from mocapflow.framework.datasets import StepOutput

        db_ds, q_ds = inputs["database"], inputs["query"]
        if db_ds.producer != "indexes.inverted" or q_ds.producer != "features.relational":
            raise PipelineError(
                f"matchers.relational needs database=indexes.inverted and query=features.relational, "
                f"got {db_ds.producer} and {q_ds.producer}"
            )
        index = InvertedIndex.load(db_ds.path / "index")
        q = q_ds.features()
        names: dict[str, int] = {}
        mdb = None
        if "motions" in inputs:
            clips = inputs["motions"].table("clips", columns=["clip_id", "name"])
            names = dict(zip(clips["name"].to_pylist(), clips["clip_id"].to_pylist(), strict=True))
            if self.params.refine:
                mdb = inputs["motions"].motions()
        elif self.params.refine:
            raise ConfigError("matchers.relational: refine needs the 'motions' input")
        self._numeric = self._numeric_costs(inputs.get("numeric"))
        rows: list[dict[str, Any]] = []
        queries = list(enumerate(self.params.queries))
        for qid, spec in ctx.progress(queries, total=len(queries), desc=f"{ctx.step_id}: queries"):
            cid = spec.clip if isinstance(spec.clip, int) else names.get(spec.clip)
            if cid is None:
                raise ConfigError(
                    f"query {qid}: unknown clip {spec.clip!r}" + ("" if names else " (give 'motions' to use names)")
                )
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
            ids = ",".join(
                FEATURE_IDS[c] for c in sorted({feature_column(k) for p in scene.progressions for st in p for k in st})
            )
            rows += [
                {**r, "features": ids} for r in self._rows(len(self.params.queries) + sid, index, hits, None, None)
            ]
        return StepOutput(
            {"data": hits_table(rows, self.params.refine)},
            {"queries": len(self.params.queries) + len(self.params.scenes), "hits": len(rows)},
        )

    @staticmethod
    def _numeric_costs(nds: Dataset | None) -> dict[int, dict[int, float]] | None:
        """Per query id the least cost of each clip in a numeric matcher's match table."""
        if nds is None:
            return None
        if not nds.producer.startswith("matchers."):
            raise PipelineError(
                f"matchers.relational: numeric must be a matcher step (matchers.search), got {nds.producer}"
            )
        t = nds.table("data", columns=["query_id", "clip_id", "cost"])
        out: dict[int, dict[int, float]] = {}
        for q, c, v in zip(t["query_id"].to_pylist(), t["clip_id"].to_pylist(), t["cost"].to_pylist(), strict=True):
            per = out.setdefault(int(q), {})
            if v is not None and v < per.get(int(c), np.inf):
                per[int(c)] = float(v)
        return out

    @staticmethod
    def _clip_id(clip: str | int, names: dict[str, int], qid: int) -> int:
        cid = clip if isinstance(clip, int) else names.get(clip)
        if cid is None:
            raise ConfigError(
                f"query {qid}: unknown example clip {clip!r}" + ("" if names else " (give 'motions' to use names)")
            )
        return int(cid)

    def _auto_rows(
        self,
        qid: int,
        index: InvertedIndex,
        bits: np.ndarray,
        spec: ExampleQuery,
        examples: list[np.ndarray],
        whole: bool = True,
    ) -> list[dict[str, Any]]:
        """Mode auto: the example as a weighted all-feature template (:mod:`.auto`).
        ``whole``: the example covers (at least 80 % of) its clip; ``auto_mutual: auto`` checks
        hits only then, since a piece of a take is no cut whose clip could be compared with
        the hit's clip (``clip`` checks regardless)."""
        from .auto import auto_dtw_hits, auto_template
        from .template_model import frame_codes

        cache = getattr(self, "_frames", None)
        if cache is None or cache[0] is not index:
            db_bits = index.frame_bits()
            any_set = next(iter(index.sets.values()))
            cache = (
                index,
                frame_codes(db_bits),
                db_bits.mean(axis=0) if len(db_bits) else np.zeros(31),
                any_set,
                db_bits,
            )
            self._frames = cache
        _, codes, background, any_set, db_bits = cache
        t = auto_template(bits, background, examples)
        if spec.features:
            allowed = sorted({feature_column(f) for f in spec.features})
            keep = np.intersect1d(t.columns, allowed)
            t.columns = keep if len(keep) else np.asarray(allowed, np.int64)
        pr = self.params
        mutual = "off" if pr.auto_mutual == "auto" and not whole else pr.auto_mutual
        s, e, c = auto_dtw_hits(
            t, bits, db_bits, codes, any_set.clip_offsets, background, mutual, pr.relative_cut, pr.mutual_ratio
        )
        numeric = getattr(self, "_numeric", None)
        if numeric is not None and pr.fusion is not None:  # relational + numeric fusion (auto.fusion_mask)
            from .auto import fusion_mask

            per = numeric.get(qid, {})
            ncost = np.array([per.get(int(c_), np.inf) for c_ in any_set.clip_ids], np.float64)
            keep = fusion_mask(np.searchsorted(any_set.clip_offsets, s, side="right") - 1, ncost, pr.fusion)
            s, e, c = s[keep], e[keep], c[keep]
        hits = Hits(
            np.searchsorted(any_set.clip_offsets, s, side="right") - 1,
            s,
            e,
            c,
            sets="+".join(sorted({feature_set_of(int(x)) for x in t.columns})),
            n_levels=t.n_frames,
        )
        rows = self._rows(qid, index, hits, None, None)
        ids = ",".join(FEATURE_IDS[int(x)] for x in sorted(t.columns))
        for r in rows:
            r.update(mode="auto", features=ids, dtw_cost=r["cost"])
        return rows

    def _rows(
        self, qid: int, index: InvertedIndex, hits: Hits, mdb: Any, query_clip: tuple[int, int] | None
    ) -> list[dict[str, Any]]:
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
            row = {
                "query_id": qid,
                "rank": rank,
                "clip_id": int(any_set.clip_ids[pos]),
                "start_frame": int(hits.start[h] - first),
                "end_frame": int(hits.end[h] - first),
                "cost": float(hits.cost[h]),
                "mode": self.params.mode if query_clip else "scene",
                "feature_sets": hits.sets,
                "n_segments": hits.n_levels,
                "mismatches": int(hits.extra.get("mismatches", np.zeros(len(hits), np.int64))[h]),
                "dtw_cost": None,
                "path": None,
                "features": hits.sets,
            }
            if mdb is not None and query_clip is not None and hits.levels is not None:
                assert hits.query_levels is not None  # set with hits.levels (single-set hits)
                row.update(self._refine(mdb, query_clip, pos, hits.levels[h] - first, hits.query_levels, index))
            out.append(row)
        return out

    def _refine(
        self,
        mdb: Any,
        query_clip: tuple[int, int],
        pos: int,
        levels: np.ndarray,
        query_levels: np.ndarray,
        index: InvertedIndex,
    ) -> dict[str, Any]:
        any_set = next(iter(index.sets.values()))
        where = {int(c): i for i, c in enumerate(mdb.clip_ids)}
        qm = mdb.motions[where[query_clip[0]]]
        dm = mdb.motions[where[int(any_set.clip_ids[pos])]]
        ql = query_levels + query_clip[1]
        qa = pose_features(qm.canonical_positions()[ql[0, 0] : ql[-1, 1]])
        da = pose_features(dm.canonical_positions()[levels[0, 0] : levels[-1, 1]])
        cost, path, _ = refine(qa, da, ql, levels, self.params.margin)
        path = path + np.array([ql[0, 0], levels[0, 0]])
        return {"dtw_cost": cost if np.isfinite(cost) else None, "path": path.tolist()}


def hits_table(rows: list[dict[str, Any]], with_path: bool = False) -> pa.Table:
    """Rows -> a match table (:data:`~mocapflow.framework.schema.MATCHES` + relational columns)."""
    fields = list(MATCHES) + [
        pa.field("mode", pa.string()),
        pa.field("feature_sets", pa.string()),
        pa.field("n_segments", pa.int32()),
        pa.field("mismatches", pa.int32()),
        pa.field("dtw_cost", pa.float64()),
        pa.field("features", pa.string()),
    ]
    if with_path:
        fields.append(WARPING_PATH)
    schema = pa.schema(fields)
    return pa.table({f.name: pa.array([r[f.name] for r in rows], f.type) for f in schema}, schema=schema)


__all__ = ["ExampleQuery", "RelationalMatcher", "SceneQuery", "dtw_band", "hits_table", "pose_features", "refine"]
