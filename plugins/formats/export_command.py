"""``mocapflow export``: the hits or segments of a workspace table written as clips in their
source's own format, rate, skeleton and joint names (:mod:`mocapflow.framework.export`).
Imports nothing numerical at module level (the command is listed by ``mocapflow --help``)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mocapflow.framework.commands import CommandContext


class ExportCommand:
    """``mocapflow export WORKSPACE [--step STEP | --hits FILE] [--output DIR] [--handle N] [--top N] [--format F]``."""

    name = "export"
    help = "write the hits or segments of a workspace table as clips (source format, rate and rig) with an index CSV"

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("workspace", help="directory written by 'mocapflow run'")
        parser.add_argument(
            "--step",
            help="the step whose table to export (a search, templates or cleaning step); default: the only one",
        )
        parser.add_argument(
            "--hits",
            metavar="FILE",
            help="export the matches of `mocapflow search --out FILE` (.csv or .parquet) instead of a step's table",
        )
        parser.add_argument(
            "--output", "-o", metavar="DIR", help="where the clips go (default WORKSPACE/export/STEP or .../HITS)"
        )
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
        from mocapflow.framework.output_paths import refuse_dataset_path

        ws = Path(args.workspace)
        if not ws.is_dir():
            raise ConfigError(f"workspace {ws} does not exist (run a pipeline first)")
        if args.handle < 0 or (args.top is not None and args.top < 1):
            raise ConfigError("--handle must be >= 0 and --top >= 1")
        if args.output:  # refused before any work
            refuse_dataset_path(args.output, "--output", workspaces=[ws], directory=True)
        datasets = read_datasets(ws)
        if getattr(args, "hits", None):
            if args.step:
                raise ConfigError("--hits and --step: give one (a search's matches file, or a step's table)")
            hits = Path(args.hits)
            segments = hits_segments(hits, datasets, ws, top=args.top)
            default_out = ws / "export" / hits.stem
            step = None
        else:
            step = args.step or _only_segment_step(datasets, ws)
            if step not in datasets:
                raise ConfigError(f"{ws}: no step {step!r} (steps: {', '.join(sorted(datasets)) or 'none'})")
            segments = workspace_segments(datasets[step], datasets, top=args.top)
            default_out = ws / "export" / step
        regs = ctx.registries()
        readers = _reader_params(datasets, step) if step else {}
        out = refuse_dataset_path(
            Path(args.output) if args.output else default_out, "--output", workspaces=[ws], directory=True
        )
        index = export_segments(segments, out, regs, handle=args.handle, format=args.format, readers=readers)
        queries = len(set(index["query"].to_pylist()))
        print(
            f"wrote {index.num_rows} clips for {queries} queries to {out} (index: {out / 'index.csv'})", file=sys.stderr
        )
        return 0


def _segment_steps(datasets: Mapping[str, Any]) -> list[str]:
    out = []
    for step, ds in datasets.items():
        try:
            names = set(ds.schema("data").names)
        except Exception:  # a dataset without a data table
            continue
        if {"clip_id", "start_frame", "end_frame"} <= names or {"clip_id", "frame", "flagged"} <= names:
            out.append(step)
    return sorted(out)


def _only_segment_step(datasets: Mapping[str, Any], ws: Path) -> str:
    from mocapflow.framework.errors import ConfigError

    steps = _segment_steps(datasets)
    if len(steps) != 1:
        raise ConfigError(
            f"{ws}: {'no step has' if not steps else 'several steps have'} segments to export; "
            f"choose one with --step ({', '.join(steps) or 'none'})"
        )
    return steps[0]


def _reader_params(datasets: Mapping[str, Any], step: str) -> dict[str, Any]:
    """The ``readers`` parameters of the ingest step the exported rows come from."""
    from mocapflow.framework.export import motions_of

    mds = motions_of(datasets[step], datasets)
    return dict(mds.manifest.get("params", {}).get("readers", {})) if mds is not None else {}


def hits_segments(hits: Path, datasets: Mapping[str, Any], ws: Path, *, top: int | None = None) -> list[Any]:
    """Segments of the matches file ``mocapflow search --out`` wrote (``clip_id``, ``rank``,
    ``start_frame``/``end_frame`` in frames of each take's own file), traced to their source
    files through the workspace's motions datasets. One query per ``query_id`` (named after
    the file; ``query`` when the file has that column)."""
    from mocapflow.framework.errors import ConfigError
    from mocapflow.framework.export import Segment, clip_sources

    if not hits.is_file():
        raise ConfigError(f"--hits {hits}: no such file (write one with mocapflow search --out FILE)")
    if hits.suffix.lower() == ".parquet":
        import pyarrow.parquet as pq

        try:
            table = pq.read_table(hits)
        except Exception as exc:
            raise ConfigError(f"--hits {hits}: not a Parquet table ({exc})") from None
    else:
        import pyarrow.csv as pacsv

        try:
            table = pacsv.read_csv(hits)
        except Exception as exc:
            raise ConfigError(f"--hits {hits}: not a CSV table ({exc})") from None
    need = {"clip_id", "start_frame", "end_frame"}
    if not need <= set(table.column_names):
        raise ConfigError(
            f"--hits {hits}: needs the columns clip_id, start_frame, end_frame (as mocapflow search --out writes); "
            f"has {', '.join(table.column_names)}"
        )
    clips: dict[int, Any] = {}
    for ds in datasets.values():
        if ds.has_table("clips") and "source_fps" in ds.schema("clips").names:
            clips.update(clip_sources(ds))
    rows = table.to_pylist()
    several = len({r.get("query_id") for r in rows}) > 1
    out: list[Any] = []
    ranks: dict[Any, int] = {}
    for line, r in enumerate(rows, start=2):
        query = str(r.get("query") or (f"{hits.stem}_{r.get('query_id')}" if several else hits.stem))
        rank = int(r.get("rank") or ranks.get(query, 0) + 1)
        ranks[query] = rank
        if top is not None and rank > top:
            continue
        c = clips.get(int(r["clip_id"]))
        if c is None:
            raise ConfigError(f"--hits {hits}, row {line - 1}: clip {r['clip_id']} is not a clip of {ws}")
        out.append(Segment(query, rank, str(c["name"]), str(c["path"]), int(r["start_frame"]), int(r["end_frame"])))
    return sorted(out, key=lambda s: (s.query, s.rank))
