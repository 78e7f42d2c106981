"""``mocapflow export``: the hits or segments of a workspace table written as clips in their
source's own format, rate, skeleton and joint names (:mod:`mocapflow.framework.export`).
Imports nothing numerical at module level (the command is listed by ``mocapflow --help``)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from mocapflow.framework.commands import CommandContext


class ExportCommand:
    """``mocapflow export WORKSPACE [--step STEP] [--output DIR] [--handle N] [--top N] [--format F]``."""

    name = "export"
    help = "write the hits or segments of a workspace table as clips (source format, rate and rig) with an index CSV"

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("workspace", help="directory written by 'mocapflow run'")
        parser.add_argument(
            "--step",
            help="the step whose table to export (a search, templates or cleaning step); default: the only one",
        )
        parser.add_argument("--output", "-o", metavar="DIR", help="where the clips go (default WORKSPACE/export/STEP)")
        parser.add_argument("--handle", type=int, default=0, metavar="N", help="extra source frames on each side")
        parser.add_argument("--top", type=int, default=None, metavar="N", help="only the N best hits per query")
        parser.add_argument(
            "--format", default=None, metavar="NAME", help="writer (bvh, amc...; default: each source's own format)"
        )

    @classmethod
    def run(cls, args: argparse.Namespace, ctx: CommandContext) -> int:
        from mocapflow.framework.datasets import read_datasets
        from mocapflow.framework.errors import ConfigError
        from mocapflow.framework.export import export_segments, workspace_segments
        from mocapflow.framework.workspace import refuse_dataset_path

        ws = Path(args.workspace)
        if not ws.is_dir():
            raise ConfigError(f"workspace {ws} does not exist (run a pipeline first)")
        if args.handle < 0 or (args.top is not None and args.top < 1):
            raise ConfigError("--handle must be >= 0 and --top >= 1")
        if args.output:  # refused before any work
            refuse_dataset_path(args.output, "--output", workspaces=[ws], directory=True)
        datasets = read_datasets(ws)
        step = args.step or _only_segment_step(datasets, ws)
        if step not in datasets:
            raise ConfigError(f"{ws}: no step {step!r} (steps: {', '.join(sorted(datasets)) or 'none'})")
        segments = workspace_segments(datasets[step], datasets, top=args.top)
        regs = ctx.registries()
        readers = _reader_params(datasets, step)
        out = refuse_dataset_path(
            Path(args.output) if args.output else ws / "export" / step, "--output", workspaces=[ws], directory=True
        )
        index = export_segments(segments, out, regs, handle=args.handle, format=args.format, readers=readers)
        queries = len(set(index["query"].to_pylist()))
        print(
            f"wrote {index.num_rows} clips for {queries} queries to {out} (index: {out / 'index.csv'})", file=sys.stderr
        )
        return 0


def _segment_steps(datasets) -> list[str]:
    out = []
    for step, ds in datasets.items():
        try:
            names = set(ds.schema("data").names)
        except Exception:  # a dataset without a data table
            continue
        if {"clip_id", "start_frame", "end_frame"} <= names or {"clip_id", "frame", "flagged"} <= names:
            out.append(step)
    return sorted(out)


def _only_segment_step(datasets, ws: Path) -> str:
    from mocapflow.framework.errors import ConfigError

    steps = _segment_steps(datasets)
    if len(steps) != 1:
        raise ConfigError(
            f"{ws}: {'no step has' if not steps else 'several steps have'} segments to export; "
            f"choose one with --step ({', '.join(steps) or 'none'})"
        )
    return steps[0]


def _reader_params(datasets, step: str) -> dict:
    """The ``readers`` parameters of the ingest step the exported rows come from."""
    from mocapflow.framework.export import motions_of

    mds = motions_of(datasets[step], datasets)
    return dict(mds.manifest.get("params", {}).get("readers", {})) if mds is not None else {}
