"""Built-in plugin: ``mocapflow report WORKSPACE [--output DIR]``, a static HTML report."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mocapflow.framework.plugins import hookimpl

if TYPE_CHECKING:
    import pyarrow as pa

    from mocapflow.framework.commands import CommandContext


@hookimpl
def register_commands() -> list[type]:
    return [ReportCommand]


def workspace_tables(workspace: Path) -> tuple[dict[str, Any], pa.Table, pa.Table]:
    """Datasets by step id, and the clips (with duration) and rejects of every motions
    dataset through the catalog, each table with a leading ``step`` column."""
    import pyarrow as pa

    from mocapflow.framework.catalog import Catalog

    clips, rejects = [], []
    with Catalog(workspace) as cat:
        datasets = dict(cat.datasets)
        for step, ds in sorted(datasets.items(), key=lambda kv: (kv[1].manifest.get("created", ""), kv[0])):
            if ds.has_table("clips"):
                rel = cat.relation(f"{step}_clips")
                # markers clips have no subject nor source rate: null columns, one table layout
                have = set(rel.columns)
                types = {"subject": "VARCHAR", "source_fps": "DOUBLE", "source_frames": "INTEGER"}
                col = {c: c if c in have else f"CAST(NULL AS {t}) AS {c}" for c, t in types.items()}
                t = (
                    rel.project(
                        f"clip_id, name, {col['subject']}, format, fps, n_frames, "
                        f"round(n_frames / fps, 3) AS duration_s, {col['source_fps']}, {col['source_frames']}, path"
                    )
                    .order("path, clip_id")
                    .to_arrow_table()
                )
                clips.append(t.add_column(0, "step", pa.array([step] * t.num_rows, pa.string())))
            if ds.has_table("rejects"):
                t = cat.relation(f"{step}_rejects").project("path, line, message").to_arrow_table()
                rejects.append(t.add_column(0, "step", pa.array([step] * t.num_rows, pa.string())))
    empty_clips = pa.table({c: pa.array([], pa.string()) for c in ("step", "clip_id", "name")})
    empty_rejects = pa.table({c: pa.array([], pa.string()) for c in ("step", "path", "line", "message")})
    return (
        datasets,
        pa.concat_tables(clips) if clips else empty_clips,
        pa.concat_tables(rejects) if rejects else empty_rejects,
    )


def build_report(workspace: str | Path, output: str | Path | None = None) -> dict[str, Any]:
    """Read a workspace written by ``mocapflow run`` and write its report site to ``output``
    (default ``<workspace>/report``); returns ``index`` (Path of index.html), ``files``,
    ``bytes``, ``steps``."""
    from mocapflow.framework.output_paths import refuse_dataset_path

    from .model import ModelBuilder
    from .site import write_site

    ws = Path(workspace)
    dest = refuse_dataset_path(ws / "report" if output is None else output, "--output", workspaces=[ws], directory=True)
    datasets, clips, rejects = workspace_tables(ws)
    model = ModelBuilder(datasets, clips, rejects).build(title=ws.resolve().name)
    info = write_site(model, ws, dest)
    return {**info, "steps": len(model.page["steps"])}


class ReportCommand:
    """``mocapflow report WORKSPACE [--output DIR]``: the results of a run as a static site."""

    name = "report"
    help = "write a static HTML report of a workspace (clips, searches with a 3-D player, digression maps)"

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("workspace", help="directory written by 'mocapflow run'")
        parser.add_argument("--output", "-o", metavar="DIR", help="site directory (default WORKSPACE/report)")

    @classmethod
    def run(cls, args: argparse.Namespace, ctx: CommandContext) -> int:
        info = build_report(args.workspace, args.output)
        print(
            f"wrote {info['index']} ({info['steps']} steps, {info['files']} files, "
            f"{info['bytes'] / 1024:.0f} KiB); open it in a browser (works from file://)",
            file=sys.stderr,
        )
        return 0
