"""What the report shows, read from a finished workspace through the datasets API.

:func:`build_model` walks the workspace's datasets (in creation order) and returns a
JSON-serialisable model for the page plus the motion data files it needs. Steps are
recognised by their tables, not by component names, so third-party matchers and cleaners
appear as long as they write the shared tables:

retrieval
    a main table with the match columns (``query_id, rank, clip_id, start_frame,
    end_frame, cost``; optional ``path`` warping path) or nearest-pose rows
    (``query_clip_id, query_frame, clip_id, frame, distance``). Queries come from a
    ``queries`` table, else from the step's ``queries`` parameter (clip name and frames).
cleaning
    a ``cleaners.*`` step whose main table is an MDM (``clip_id, frame, joint_name,
    value``; optional ``flagged`` and ``cue``) with an ``edits`` table (``new_rotation`` per
    edited cell): the cleaned take is the original with the edits applied.
base poses
    a ``base_poses`` table (``cluster, clip_id, frame, n_members``).
derived motions
    a non-ingest step that writes motions (``clips``) whose clips are clips of one of its
    inputs (same id and checksum): reconstruction results, played over the input; or of a
    markers input (same id): reconstructions played with the input markers beside them.
markers
    a markers dataset (``clips`` with ``n_markers``, ``data`` with ``positions``): each take's
    markers played as points (y up).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from mocapflow.framework.datasets import Dataset
from mocapflow.framework.joints import CANONICAL_JOINTS
from mocapflow.framework.normalize import to_root_frame

from .sources import (
    HIT_SLOTS,
    MARKER_CLIPS,
    QUERY_SLOTS,
    _Motions,
    columns_of,
    is_markers,
    marker_positions,
    slot_motions,
)


def owned_file(root: Path, path: Path) -> bool:
    """Whether ``path`` is a regular file inside ``root`` reached without a symbolic link:
    the only files the report copies (a link named ``leak.png`` to ``/etc/passwd`` is not)."""
    p = Path(path)
    try:
        rel = p.relative_to(root)
    except ValueError:
        return False
    cur = Path(root)
    for part in rel.parts:
        cur = cur / part
        if cur.is_symlink():
            return False
    return p.is_file()


MATCH_COLS = ("query_id", "rank", "clip_id", "start_frame", "end_frame", "cost")
#: the hit in its take's own units (a matcher step appends them); the report shows start and duration
SOURCE_UNIT_COLS = (
    "fps",
    "start_s",
    "end_s",
    "start_frame_analysis",
    "end_frame_analysis",
    "fps_analysis",
    "source_fps",
    "source_start_frame",
    "source_end_frame",
)
NEAREST_COLS = ("query_clip_id", "query_frame", "clip_id", "frame", "distance")
MDM_COLS = ("clip_id", "frame", "joint_name", "value")
#: Bones of the stick figures, as canonical joint pairs along these chains.
_CHAINS = (
    "root lhip lknee lankle ltoes",
    "root rhip rknee rankle rtoes",
    "root lowerback upperback chest neck head headtop",
    "chest lclavicle lshoulder lelbow lwrist lfingers",
    "chest rclavicle rshoulder relbow rwrist rfingers",
)
BONES = tuple(pair for chain in _CHAINS for pair in pairwise(chain.split()))
SMALL_TABLE_ROWS = 60


@dataclass
class Model:
    """The page model (JSON-serialisable, read by ``assets/report.js``) and the motion data
    the site writer must emit: ``motions`` key -> (T, 25, 3) canonical positions in metres
    per played take, ``fps`` their frame rates, ``cleaning`` key -> arrays per cleaned clip
    (cleaned positions, MDM, cues)."""

    page: dict[str, Any]
    motions: dict[str, np.ndarray] = field(default_factory=dict)
    fps: dict[str, float] = field(default_factory=dict)
    cleaning: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: ``k/<step>/<clip>`` -> (T, M, 3) marker positions in metres, y up, NaN in gaps
    markers: dict[str, np.ndarray] = field(default_factory=dict)


def _scalar(v: Any) -> Any:
    if isinstance(v, float) and not np.isfinite(v):
        return None
    if isinstance(v, (list, tuple, dict)):
        return str(v) if len(str(v)) < 200 else str(v)[:197] + "..."
    return v


def small_table(t: pa.Table, max_rows: int = SMALL_TABLE_ROWS) -> dict[str, Any]:
    """A table for the page: scalar columns, at most ``max_rows`` rows."""
    cols = [
        f.name
        for f in t.schema
        if not (pa.types.is_list(f.type) or pa.types.is_fixed_size_list(f.type) or pa.types.is_large_list(f.type))
    ]
    rows = [[_scalar(r[c]) for c in cols] for r in t.select(cols).slice(0, max_rows).to_pylist()]
    return {"columns": cols, "rows": rows, "n_rows": t.num_rows}


class ModelBuilder:
    """Builds the :class:`Model` of a workspace (see the module docstring)."""

    def __init__(self, datasets: Mapping[str, Dataset], clips: pa.Table, rejects: pa.Table) -> None:
        self.datasets = datasets
        self.mo = _Motions(datasets)
        self._markers: dict[str, dict[int, tuple[dict[str, Any], np.ndarray]]] = {}
        self.model = Model(page={})
        self.clips, self.rejects = clips, rejects

    def motion_key(self, step: str, clip_id: int) -> str:
        key = f"m/{step}/{int(clip_id)}"
        if key not in self.model.motions:
            self.model.motions[key] = self.mo.positions(step, clip_id)
            self.model.fps[key] = self.mo.fps(step, clip_id)
        return key

    def build(self, title: str) -> Model:
        steps = [self.step(ds) for ds in step_order(self.datasets)]
        self.model.page.update(
            {
                "title": title,
                "joints": list(CANONICAL_JOINTS),
                "bones": [[CANONICAL_JOINTS.index(a), CANONICAL_JOINTS.index(b)] for a, b in BONES],
                "clips": small_table(self.clips, max_rows=100000),
                "rejects": small_table(self.rejects, max_rows=100000),
                "steps": steps,
            }
        )
        return self.model

    def step(self, ds: Dataset) -> dict[str, Any]:
        m = ds.manifest
        out: dict[str, Any] = {
            "id": ds.step,
            "component": ds.producer,
            "kind": ds.producer_kind,
            "version": m.get("version"),
            "created": m.get("created"),
            "seconds": m.get("seconds"),
            "fingerprint": m.get("fingerprint"),
            "pipeline": m.get("pipeline"),
            "params": m.get("params", {}),
            "summary": m.get("summary", {}),
            "inputs": {k: v.get("step") for k, v in m.get("inputs", {}).items()},
            "input_fingerprints": {k: v.get("fingerprint") for k, v in m.get("inputs", {}).items()},
            "tables": {t: int(n) for t, n in m.get("tables", {}).items()},
            "images": sorted(str(p.relative_to(ds.path)) for p in ds.path.rglob("*.png") if owned_file(ds.path, p)),
            "views": [],
        }
        names = ds.table_names()
        data_cols = columns_of(ds, "data") if "data" in names else []
        try:
            if all(c in data_cols for c in MATCH_COLS):
                out["views"].append(self.retrieval(ds))
            elif all(c in data_cols for c in NEAREST_COLS):
                out["views"].append(self.nearest(ds))
            if ds.producer_kind == "cleaners" and all(c in data_cols for c in MDM_COLS) and "edits" in names:
                out["views"].append(self.cleaning(ds))
            if "base_poses" in names:
                out["views"].append(self.base_poses(ds))
            if is_markers(ds):
                out["views"].append(self.markers(ds))
            elif "clips" in names and ds.producer_kind != "formats":
                view = self.derived(ds)
                if view is not None:
                    out["views"].append(view)
        except (KeyError, ValueError, IndexError) as exc:  # a step the report cannot read is shown without its view
            out["view_error"] = f"{type(exc).__name__}: {exc}"
        out["small_tables"] = {
            t: small_table(ds.table(t))
            for t in names
            if t not in ("clips", "skeletons", "rotations")
            and int(m.get("tables", {}).get(t, 10**9)) <= SMALL_TABLE_ROWS
        }
        return out

    # --- retrieval --------------------------------------------------------------------------
    def _query_specs(self, ds: Dataset, step: str) -> dict[int, dict[str, Any]]:
        names = {v: k for k, v in self.mo.names(step).items()}
        if ds.has_table("queries"):
            rows = ds.table("queries").to_pylist()
            # start/end: analysis-rate frames (what the player steps through); frames: the take's own
            return {
                int(r["query_id"]): {
                    "name": r.get("name") or f"query {r['query_id']}",
                    "clip_id": r.get("clip_id"),
                    "start": r.get("start_frame_analysis", r.get("start_frame")),
                    "end": r.get("end_frame_analysis", r.get("end_frame")),
                    "frames": f"[{r.get('start_frame')}, {r.get('end_frame')})",
                }
                for r in rows
            }
        out = {}
        for i, q in enumerate(ds.manifest.get("params", {}).get("queries", []) or []):
            if not isinstance(q, dict) or q.get("clip") is None:
                continue
            cid = q["clip"] if isinstance(q["clip"], int) else names.get(str(q["clip"]))
            if cid is None:
                continue
            n = len(self.mo.positions(step, cid))
            start, end = int(q.get("start_frame") or 0), q.get("end_frame")
            label = ", ".join(q.get("features", ()))
            out[i] = {
                "name": f"{self.mo.names(step)[cid]}[{start}:{end if end is not None else n}]"
                + (f" ({label})" if label else ""),
                "clip_id": cid,
                "start": start,
                "end": int(end) if end is not None else n,
            }
        return out

    def _steps(self, ds: Dataset) -> tuple[str, str]:
        hit_step = slot_motions(ds, self.datasets, HIT_SLOTS)
        query_step = slot_motions(ds, self.datasets, QUERY_SLOTS)
        if hit_step is None or query_step is None:
            raise KeyError("no motions dataset upstream")
        return hit_step, query_step

    def retrieval(self, ds: Dataset) -> dict[str, Any]:
        step, qstep = self._steps(ds)
        t = ds.table("data")
        cols = t.column_names
        extra = [
            c
            for c in cols
            if c not in MATCH_COLS
            and c not in SOURCE_UNIT_COLS
            and c not in ("path", "path_analysis")
            and not pa.types.is_nested(t.schema.field(c).type)
        ]
        # a matcher step's table: frames of each take's own file, the analysis-rate ones in *_analysis
        pcol = "path_analysis" if "path_analysis" in cols else "path"
        analysis = "start_frame_analysis" in cols
        names, qnames = self.mo.names(step), self.mo.names(qstep)
        queries = {}
        for qid, q in self._query_specs(ds, qstep).items():
            queries[qid] = {**q, "id": qid}
            # a query from a file (clip_id -1) or a scene description has no take to play
            if q.get("clip_id") is not None and q.get("start") is not None and int(q["clip_id"]) in qnames:
                queries[qid].update(clip=qnames[int(q["clip_id"])], motion=self.motion_key(qstep, q["clip_id"]))
        hits = []
        paths = t[pcol].to_pylist() if pcol in cols else [None] * t.num_rows
        for r, path in zip(t.select([c for c in cols if c != pcol]).to_pylist(), paths, strict=True):
            qid = int(r["query_id"])
            q = queries.setdefault(qid, {"id": qid, "name": f"query {qid}", "clip_id": None})
            a, b = (
                (r["start_frame_analysis"], r["end_frame_analysis"]) if analysis else (r["start_frame"], r["end_frame"])
            )
            fps = self.mo.fps(step, r["clip_id"])
            start_s = r["start_s"] if analysis and r.get("start_s") is not None else a / fps
            end_s = r["end_s"] if analysis and r.get("end_s") is not None else b / fps
            hits.append(
                {
                    "query_id": qid,
                    "rank": r["rank"],
                    "clip_id": r["clip_id"],
                    "clip": names.get(r["clip_id"], str(r["clip_id"])),
                    "start": a,
                    "end": b,
                    "frames": f"[{r['start_frame']}, {r['end_frame']})",
                    "cost": _scalar(r["cost"]),
                    "start_s": round(start_s, 3),
                    "seconds": round(end_s - start_s, 3),
                    "extra": {c: _scalar(r[c]) for c in extra},
                    "path": _relative_path(path, q if q.get("motion") else None),
                    "motion": self.motion_key(step, r["clip_id"]),
                }
            )
        return {
            "type": "retrieval",
            "export": export_command(ds),
            "motions": step,
            "query_motions": qstep,
            "cost_label": "cost",
            "extra": extra,
            "queries": sorted(queries.values(), key=lambda q: q["id"]),
            "hits": hits,
        }

    def nearest(self, ds: Dataset) -> dict[str, Any]:
        step, qstep = self._steps(ds)
        names, qnames = self.mo.names(step), self.mo.names(qstep)
        queries: dict[Any, Any] = {}
        hits: list[Any] = []
        for r in ds.table("data").to_pylist():
            qid = int(r.get("query_id", len(queries)))
            qc, qf = int(r["query_clip_id"]), int(r["query_frame"])
            queries.setdefault(
                qid,
                {
                    "id": qid,
                    "name": f"{qnames.get(qc, qc)} frame {qf}",
                    "clip_id": qc,
                    "clip": qnames.get(qc),
                    "start": qf,
                    "end": qf + 1,
                    "motion": self.motion_key(qstep, qc),
                },
            )
            hits.append(
                {
                    "query_id": qid,
                    "rank": r.get("rank"),
                    "clip_id": r["clip_id"],
                    "clip": names.get(r["clip_id"]),
                    "start": r["frame"],
                    "end": r["frame"] + 1,
                    "cost": r["distance"],
                    "extra": {},
                    "path": [[0, 0]],
                    "seconds": round(1 / self.mo.fps(step, r["clip_id"]), 3),
                    "motion": self.motion_key(step, r["clip_id"]),
                }
            )
        return {
            "type": "retrieval",
            "export": export_command(ds),
            "motions": step,
            "query_motions": qstep,
            "cost_label": "distance",
            "extra": [],
            "poses": True,
            "queries": sorted(queries.values(), key=lambda q: q["id"]),
            "hits": hits,
        }

    # --- cleaning ---------------------------------------------------------------------------
    def cleaning(self, ds: Dataset) -> dict[str, Any]:
        from .cleaned import cleaned_positions, mdm_grid

        step = ds.manifest["inputs"]["motions"]["step"]
        mdb = self.datasets[step].motions()
        mdm, edits = ds.table("data"), ds.table("edits")
        threshold = float(ds.manifest.get("params", {}).get("threshold", 0.5))
        clips = []
        for pos, motion in enumerate(mdb.motions):
            cid = int(mdb.clip_ids[pos])
            grid = mdm_grid(mdm, cid, motion.n_frames, threshold)
            if grid is None:
                continue
            cleaned = cleaned_positions(motion, edits, cid)
            key = f"c/{ds.step}/{cid}"
            self.model.cleaning[key] = {"positions": cleaned, **grid}
            clips.append(
                {
                    "clip_id": cid,
                    "clip": motion.name,
                    "n_frames": motion.n_frames,
                    "fps": motion.fps,
                    "data": key,
                    "motion": self.motion_key(step, cid),
                    "joints": grid["joints"],
                    "cues": grid["cues"],
                    "n_flagged": int(grid["n_flagged"]),
                    "n_edits": int(np.sum(edits["clip_id"].to_numpy() == cid)),
                }
            )
        return {
            "type": "cleaning",
            "motions": step,
            "threshold": threshold,
            "clips": clips,
            "has_cue_column": "cue" in mdm.column_names,
        }

    # --- base poses, derived motions ---------------------------------------------------------
    def base_poses(self, ds: Dataset) -> dict[str, Any]:
        step = slot_motions(ds, self.datasets, ("motions", "features"))
        rows = ds.table("base_poses").to_pylist()
        names = self.mo.names(step) if step else {}
        poses = []
        for r in rows[:200]:
            p = None
            if step:
                # in the root frame (root at the origin, facing +z), as base_poses.png draws them
                p = to_root_frame(self.mo.positions(step, r["clip_id"])[r["frame"]][None], CANONICAL_JOINTS)[0]
            poses.append(
                {
                    **r,
                    "clip": names.get(r["clip_id"], str(r["clip_id"])),
                    "motion": self.motion_key(step, r["clip_id"]) if step else None,
                    "positions": None
                    if p is None
                    else [None if not np.isfinite(v) else round(float(v), 4) for v in p.reshape(-1)],
                }
            )
        return {"type": "base_poses", "motions": step, "poses": poses, "n_base_poses": len(rows)}

    def marker_key(self, step: str, clip_id: int) -> str:
        key = f"k/{step}/{int(clip_id)}"
        if key not in self.model.markers:
            if step not in self._markers:
                self._markers[step] = marker_positions(self.datasets[step])
            row, pos = self._markers[step][int(clip_id)]
            self.model.markers[key] = pos
            self.model.fps[key] = float(row["fps"])
        return key

    def markers(self, ds: Dataset) -> dict[str, Any]:
        """The takes of a markers dataset, each played as its markers."""
        self._markers[ds.step] = found = marker_positions(ds)
        clips = []
        for cid, (row, pos) in sorted(found.items(), key=lambda kv: (kv[1][0]["path"], kv[0]))[:MARKER_CLIPS]:
            clips.append(
                {
                    "clip_id": cid,
                    "clip": row["name"],
                    "n_frames": int(pos.shape[0]),
                    "n_markers": int(pos.shape[1]),
                    "fps": float(row["fps"]),
                    "labels": list(row["labels"] or ()),
                    "markers": self.marker_key(ds.step, cid),
                }
            )
        return {"type": "markers", "clips": clips, "n_clips": len(found)}

    def derived(self, ds: Dataset) -> dict[str, Any] | None:
        cols = ["clip_id", "name", "checksum", "n_frames"]
        mine = ds.table("clips", columns=cols).to_pylist()
        candidates = []
        marker_pairs = []
        for name, ref in ds.manifest.get("inputs", {}).items():
            other = self.datasets.get(ref["step"])
            if other is not None and is_markers(other):
                # the takes were computed from these markers (same clip id): played beside them
                if other.step not in self._markers:
                    self._markers[other.step] = marker_positions(other)
                theirs_mk = self._markers[other.step]
                for r in mine:
                    if r["clip_id"] in theirs_mk:
                        marker_pairs.append(
                            {
                                "clip_id": r["clip_id"],
                                "clip": r["name"],
                                "source_clip": theirs_mk[r["clip_id"]][0]["name"],
                                "source_step": other.step,
                                "input": name,
                                "n_frames": r["n_frames"],
                                "motion": self.motion_key(ds.step, r["clip_id"]),
                                "markers": self.marker_key(other.step, r["clip_id"]),
                            }
                        )
            elif other is not None and other.has_table("clips"):
                theirs = {
                    (r["clip_id"], r["checksum"], r["n_frames"]): r["name"]
                    for r in other.table("clips", columns=cols).to_pylist()
                }
                hits = sum((r["clip_id"], r["checksum"], r["n_frames"]) in theirs for r in mine)
                candidates.append((-hits, len(theirs), name, other, theirs))
        pairs: list[dict[str, Any]] = []
        # the input that holds most of these clips and least else (the test takes, not the prior)
        for _, _, name, other, theirs in sorted(candidates, key=lambda c: c[:3]):
            for r in mine:
                src = theirs.get((r["clip_id"], r["checksum"], r["n_frames"]))
                if src is not None and not any(p["clip_id"] == r["clip_id"] for p in pairs):
                    pairs.append(
                        {
                            "clip_id": r["clip_id"],
                            "clip": r["name"],
                            "source_clip": src,
                            "source_step": other.step,
                            "input": name,
                            "n_frames": r["n_frames"],
                            "motion": self.motion_key(ds.step, r["clip_id"]),
                            "source_motion": self.motion_key(other.step, r["clip_id"]),
                        }
                    )
        pairs += [p for p in marker_pairs if not any(q["clip_id"] == p["clip_id"] for q in pairs)]
        return {"type": "derived", "pairs": pairs} if pairs else None


def _relative_path(path: list[Any] | None, query: dict[str, Any] | None) -> list[list[int]] | None:
    """Warping path with query frames relative to the query's first frame.

    Matchers differ: LNG and subsequence DTW give query frames from 0, relational DTW
    refinement gives frames within the query clip. Frames that all fit ``[0, n_query)`` are
    taken as relative; otherwise the query's start is subtracted.
    """
    if path is None or query is None or query.get("start") is None:
        return [list(map(int, p)) for p in path] if path else None
    start, n = int(query["start"]), int(query["end"]) - int(query["start"])
    p = np.asarray(path, np.int64).reshape(-1, 2)
    if len(p) and (p[:, 0].max() >= n or p[:, 0].min() < 0):
        p[:, 0] -= start
    return p.tolist()


def step_order(datasets: Mapping[str, Dataset]) -> list[Dataset]:
    """Datasets with every input before its consumers, else in creation order (then by id)."""
    left = dict(datasets)
    out: list[Dataset] = []
    while left:
        ready = [
            d for d in left.values() if not any(v.get("step") in left for v in d.manifest.get("inputs", {}).values())
        ] or list(left.values())
        first = min(ready, key=lambda d: (d.manifest.get("created", ""), d.step))
        out.append(first)
        del left[first.step]
    return out


def export_command(ds: Dataset) -> str:
    """The ``mocapflow export`` command line that writes a step's hits as clips."""
    import shlex

    return f"mocapflow export {shlex.quote(str(ds.path.parent.resolve()))} --step {shlex.quote(ds.step)} --handle 10"
