"""Built-in plugin: the MDM cleaner, its evaluation harness and ``mocapflow clean``."""
from __future__ import annotations

import argparse
import json
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from mocapflow.framework.plugins import hookimpl


@hookimpl
def register_cleaners() -> list[type]:
    from .mdm import MDMCleaner

    return [MDMCleaner]


@hookimpl
def register_analyses() -> list[type]:
    from mocapflow.plugins.analyses.clean_eval import CleaningEvaluation

    return [CleaningEvaluation]


@hookimpl
def register_commands() -> list[type]:
    return [CleanCommand]


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "clip"


def mdm_table(res: Any, motion: Any, mdm_in: np.ndarray, clip_id: int, threshold: float) -> pa.Table:
    """MDM rows at the input frames: clip_id, frame, joint, joint_name, value, flagged."""
    cols = res.texture.joint_index
    t = motion.n_frames
    vals = mdm_in[:, cols]  # (T, m)
    frame = np.repeat(np.arange(t, dtype=np.int32), len(cols))
    joint = np.tile(cols.astype(np.int32), t)
    names = np.tile(np.array(res.texture.joints, dtype=object), t)
    return pa.table({
        "clip_id": pa.array(np.full(t * len(cols), clip_id, np.int32)),
        "frame": pa.array(frame),
        "joint": pa.array(joint),
        "joint_name": pa.array(names.tolist(), pa.string()),
        "value": pa.array(vals.reshape(-1).astype(np.float32)),
        "flagged": pa.array(vals.reshape(-1) > threshold),
    })


def clean_clip(cleaner: Any, motion: Any, context: Any, clip_id: int, out_dir: Path | None) -> dict[str, Any]:
    """Analyse and repair one clip; write its BVH and heatmap into ``out_dir``."""
    from .plots import mdm_heatmap
    from .repair import map_to_input, repair_motion

    p = cleaner.params
    res = cleaner.analyse(motion, context)
    cleaned, edits = repair_motion(motion, res, p)
    edits = edits.set_column(0, "clip_id", pa.array(np.full(edits.num_rows, clip_id, np.int32)))
    mdm_in = map_to_input(res, motion)
    files = {}
    if out_dir is not None:
        stem = _safe(motion.name or f"clip{clip_id}")
        if p.heatmaps:
            files["heatmap"] = str(mdm_heatmap(res.mdm, res.joints, out_dir / f"{stem}.mdm.png", res.texture.fps,
                                               p.threshold, title=f"{motion.name}: movement digression map"))
        if p.write_bvh:
            from mocapflow.plugins.formats.bvh import write_bvh

            write_bvh(cleaned, out_dir / f"{stem}.clean.bvh")
            files["bvh"] = str(out_dir / f"{stem}.clean.bvh")
    return {
        "mdm": mdm_table(res, motion, mdm_in, clip_id, p.threshold),
        "edits": edits,
        "cleaned": cleaned,
        "summary": {"clip": motion.name, "seconds": round(res.seconds, 3), "dtw": res.n_dtw,
                    "flagged_cells": int((res.mdm > p.threshold).sum()), "edited_cells": edits.num_rows, **files},
    }


def _clean_task(cleaner: Any, context: Any, out_dir: Path, motion: Any, clip_id: int) -> dict[str, Any]:
    """One clip of :func:`run_cleaner` (module-level: executors pickle it); the context
    motions are read once per worker process."""
    out = clean_clip(cleaner, motion, context.motions() if context is not None else None, clip_id, out_dir)
    out.pop("cleaned")  # the BVH is written; the motion itself need not travel back
    return out


def run_cleaner(cleaner: Any, inputs: Mapping[str, Any], ctx: Any) -> Any:
    """``cleaners.mdm`` as a pipeline step: every clip of ``motions`` against itself plus the
    optional ``context`` dataset. Tables ``data`` (MDM), ``edits``; files per clip."""
    from mocapflow.framework.datasets import StepOutput

    from functools import partial

    from mocapflow.framework.executors import DatasetRef

    # clips and context go to the workers by reference (each reads them from the workspace)
    context = DatasetRef.of(inputs["context"]) if inputs.get("context") is not None else None
    mdms, edits, summary = [], [], []
    for out in ctx.map_clips(partial(_clean_task, cleaner, context, ctx.out_dir), inputs["motions"], with_ids=True):
        mdms.append(out["mdm"])
        edits.append(out["edits"])
        summary.append(out["summary"])
    data = pa.concat_tables(mdms) if mdms else None
    ed = pa.concat_tables(edits) if edits else None
    tables = {k: v for k, v in (("data", data), ("edits", ed)) if v is not None}
    return StepOutput(tables, {"clips": summary})


def _read_motion(path: str) -> Any:
    from mocapflow.framework import load_registries
    from mocapflow.framework.errors import ConfigError

    regs = load_registries()
    ext = Path(path).suffix.lower()
    for _, cls in regs["formats"]:
        if ext in getattr(cls, "extensions", ()):
            return cls().read(path)
    raise ConfigError(f"{path}: no registered reader for {ext!r} files")


class CleanCommand:
    """``mocapflow clean TAKE --context FILES... --output CLEAN.bvh --report DIR``."""

    name = "clean"
    help = "detect and repair capture errors of a take by self-similarity (MDM, Aristidou 2018)"

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("take", help="motion file to clean (.amc, .bvh...)")
        parser.add_argument("--context", nargs="*", default=[], metavar="FILE", help="similar clean takes to search too")
        parser.add_argument("--output", required=True, metavar="CLEAN.bvh", help="cleaned take (.bvh or .amc)")
        parser.add_argument("--report", metavar="DIR", help="write mdm.parquet, edits.parquet, heatmap PNG, summary.json")
        parser.add_argument("--threshold", type=float, default=None, help="MDM threshold (default 0.5)")
        parser.add_argument("--two-stage", action="store_true", help="local search first, context only around distinct words")
        parser.add_argument("--normalization", choices=("mean", "median", "spread", "texture", "none"), default=None,
                            help="scale of the MDM differences (see cleaners.mdm normalization; mean = the paper)")

    @classmethod
    def run(cls, args: argparse.Namespace) -> int:
        import pyarrow.parquet as pq

        from .mdm import MDMCleaner

        take = _read_motion(args.take)
        context = [_read_motion(p) for p in args.context]
        params: dict[str, Any] = {"write_bvh": False, "heatmaps": bool(args.report), "two_stage": args.two_stage}
        if args.threshold is not None:
            params["threshold"] = args.threshold
        if args.normalization is not None:
            params["normalization"] = args.normalization
        cleaner = MDMCleaner(params)
        report = Path(args.report) if args.report else None
        if report is not None:
            report.mkdir(parents=True, exist_ok=True)
        out = clean_clip(cleaner, take, context, 0, report)
        dest = Path(args.output)
        if dest.suffix.lower() == ".amc":
            from mocapflow.plugins.formats.asf_amc import write_amc

            write_amc(out["cleaned"], dest)
        else:
            from mocapflow.plugins.formats.bvh import write_bvh

            write_bvh(out["cleaned"], dest)
        if report is not None:
            pq.write_table(out["mdm"], report / "mdm.parquet")
            pq.write_table(out["edits"], report / "edits.parquet")
            (report / "summary.json").write_text(json.dumps(out["summary"], indent=2))
        s = out["summary"]
        print(f"{take.name}: {s['flagged_cells']} cells flagged, {s['edited_cells']} input cells edited "
              f"in {s['seconds']:.2f} s -> {dest}", flush=True)
        return 0
