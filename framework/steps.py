"""The default step of each component kind, and :func:`run_step`, which the runner calls.

A component with a step of its own overrides ``run``; the others get the default of their
kind: a feature set transforms every clip (:func:`run_features`), an index is built over a
features dataset (:func:`run_index`), a matcher matches every query
(:func:`.queries.run_matcher`), a cleaner cleans every clip (:func:`run_cleaner`). Each
returns a :class:`~.datasets.StepOutput`; the runner writes it (:mod:`.workspace`).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from functools import partial
from pathlib import Path

import numpy as np
import pyarrow as pa

from .cleaning import CleanedClip
from .clip_refs import DatasetRef, clip_batches, read_rows, row_groups
from .components import Cleaner, Component, FeatureSet, Index, Matcher
from .context import StepContext
from .datasets import Dataset, StepOutput, feature_table, frame_id_table
from .errors import DataError
from .motion import Motion
from .queries import in_user_units, run_matcher
from .registry import Registries
from .schema import fixed_list_to_numpy
from .workspace import TableWriter

StepFunction = Callable[[Component, Mapping[str, Dataset], StepContext], StepOutput]


def run_step(component: Component, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
    """``component.run`` where the component overrides it, else the default step of its kind.
    A matcher's own ``run`` gets its match table in users' units too (:func:`.queries.in_user_units`)."""
    if type(component).run is not Component.run:
        out = component.run(inputs, ctx)
        if isinstance(component, Matcher) and "database" in inputs:
            out = in_user_units(out, inputs)
        return out
    if isinstance(component, FeatureSet):
        return run_features(component, inputs, ctx)
    if isinstance(component, Index):
        return run_index(component, inputs, ctx)
    if isinstance(component, Matcher):
        return run_matcher(component, inputs, ctx)
    if isinstance(component, Cleaner):
        return run_cleaner(component, inputs, ctx)
    return component.run(inputs, ctx)  # raises: no step of its own, none by default


def run_features(fs: FeatureSet, inputs: Mapping[str, Dataset], ctx: StepContext, stream: bool = True) -> StepOutput:
    """Features of every clip of ``motions``; a feature set that ``requires_fit`` is fitted on
    ``reference`` (motions) or loads the model of ``reference`` (a features dataset). The
    ``data`` table is streamed to the step's folder a batch of clips at a time (a
    :class:`~.workspace.TableWriter`); ``stream=False``: returned as one in-memory table (for
    a step that derives more tables from it)."""
    motions = inputs["motions"]
    if fs.requires_fit:
        ref = inputs.get("reference")
        if ref is not None and ref.producer_kind == "features":
            fs.load_state(ref.path)  # reuse a model fitted by another step
        else:
            fs.fit((ref if ref is not None else motions).motions())
        fs.save_state(ctx.out_dir)
    # clips go out by reference: each worker reads its own from the Parquet file; the table
    # is written a batch of clips at a time, so the step never holds the whole library
    clips = motions.table("clips", columns=["clip_id", "n_frames"])
    ids, lengths = clips["clip_id"].to_numpy(), clips["n_frames"].to_numpy().astype(np.int64)
    out: TableWriter | list[pa.Table] | None = None
    prev = _previous_features(fs, motions, ctx)
    reused = 0
    batches = clip_batches(motions)
    for n, (a, b) in enumerate(batches):
        desc = fs.key() + (f" ({n + 1}/{len(batches)})" if len(batches) > 1 else "")
        keep = np.array([prev is not None and int(c) in prev.clips for c in ids[a:b]], bool)
        parts: list[np.ndarray] = [np.zeros((0, fs.dim), np.float32)] * (b - a)
        for r0, r1 in _runs(~keep):  # the clips to compute, a run of consecutive ones per call
            parts[r0:r1] = ctx.map_clips(fs.transform_motion, motions, desc=desc, clips=(a + r0, a + r1))
        for r0, r1 in _runs(keep):  # the others' rows copied from the previous dataset
            assert prev is not None
            for i in range(r0, r1):
                parts[i] = prev.rows(int(ids[a + i]))
        reused += int(keep.sum())
        x = np.concatenate([np.asarray(p, np.float32) for p in parts], 0)
        if x.shape[0] != int(lengths[a:b].sum()):
            raise DataError(
                f"{fs.key()}: {x.shape[0]} feature rows for {int(lengths[a:b].sum())} frames of clips {a}..{b}"
            )
        clip_id = np.repeat(ids[a:b].astype(np.int32), lengths[a:b])
        frame = (np.arange(len(clip_id)) - np.repeat(np.cumsum(lengths[a:b]) - lengths[a:b], lengths[a:b])).astype(
            np.int32
        )
        table = feature_table(clip_id, frame, x)
        if out is None:
            out = ctx.table_writer("data", table.schema) if stream else []
        if isinstance(out, list):
            out.append(table)
        else:
            out.write(table)
    summary = {"reused_clips": reused} if prev is not None else {}
    if not out:
        empty = feature_table(np.zeros(0, np.int32), np.zeros(0, np.int32), np.zeros((0, fs.dim)))
        return StepOutput({"data": empty}, summary)
    return StepOutput({"data": pa.concat_tables(out) if isinstance(out, list) else out}, summary)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``[a, b)`` of the runs of true entries of ``mask``."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(m[1:] != m[:-1])
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


class _PreviousFeatures:
    """The feature rows of the clips the ingest copied unchanged (its ``reused`` table), from
    the step's previous dataset, when that was written by the same feature set with the same
    parameters from the motions dataset the ingest copied them from."""

    def __init__(self, ds: Dataset, clips: set[int]) -> None:
        self.ds, self.clips = ds, clips
        cid = ds.table("data", columns=["clip_id"])["clip_id"].to_numpy()
        cuts = np.concatenate([[0], np.flatnonzero(np.diff(cid)) + 1, [len(cid)]])
        self.span = {int(cid[a]): (int(a), int(b)) for a, b in zip(cuts[:-1], cuts[1:], strict=True) if b > a}
        self.clips &= set(self.span)
        self.groups = row_groups(ds.path / "data.parquet")

    def rows(self, clip_id: int) -> np.ndarray:
        """The clip's feature rows (read a row group at a time: bounded memory)."""
        a, b = self.span[clip_id]
        t = read_rows(str(self.ds.path), self.ds.fingerprint, "data", self.groups, a, b, ["features"])
        return fixed_list_to_numpy(t["features"])


def _previous_features(fs: FeatureSet, motions: Dataset, ctx: StepContext) -> _PreviousFeatures | None:
    if fs.requires_fit or not motions.has_table("reused"):
        return None
    from .errors import PipelineError

    try:
        prev = Dataset(ctx.workspace / ctx.step_id)
        same = (
            prev.producer == fs.key()
            and str(prev.manifest.get("version")) == fs.version
            and prev.manifest.get("params") == json.loads(json.dumps(fs.get_params(), default=str))
            and prev.manifest.get("inputs", {}).get("motions", {}).get("fingerprint")
            == motions.manifest.get("summary", {}).get("reused_from")
        )
        if not same:
            return None
        return _PreviousFeatures(prev, {int(c) for c in motions.table("reused")["clip_id"].to_pylist()})
    except (PipelineError, OSError, ValueError, KeyError):  # none, or unreadable: compute every clip
        return None


def run_index(index: Index, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
    """The index built over ``features`` and saved into ``index/`` of the dataset."""
    feats = inputs["features"].features()
    index.build(feats.x)
    index.save(ctx.out_dir / "index")
    # row i of the index is frame (clip_id[i], frame[i]); matchers map ids back with it
    return StepOutput({"data": frame_id_table(feats.clip_id, feats.frame)})


def _clean_task(
    cleaner: Cleaner,
    context: DatasetRef | None,
    out_dir: Path,
    registries: Registries,
    motion: Motion,
    clip_id: int,
) -> CleanedClip:
    """One clip of :func:`run_cleaner` (module-level: executors pickle it); the context
    motions are read once per worker process."""
    ctx_motions = context.motions() if context is not None else None
    out = cleaner.detect_and_repair(motion, ctx_motions, clip_id, out_dir, registries)
    out.cleaned = None  # files are written; the motion itself need not travel back
    return out


def run_cleaner(cleaner: Cleaner, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
    """Every clip of ``motions`` cleaned against itself plus the optional ``context`` dataset.
    Tables ``data`` (digressions), ``edits``; files per clip; summary ``{"clips": [...]}``."""
    # clips and context go to the workers by reference (each reads them from the workspace)
    context = DatasetRef.of(inputs["context"]) if inputs.get("context") is not None else None
    task = partial(_clean_task, cleaner, context, ctx.out_dir, ctx.registries)
    outs: list[CleanedClip] = ctx.map_clips(task, inputs["motions"], with_ids=True)
    tables = {
        name: pa.concat_tables([getattr(o, attr) for o in outs])
        for name, attr in (("data", "digressions"), ("edits", "edits"))
        if outs
    }
    return StepOutput(tables, {"clips": [o.summary for o in outs]})
