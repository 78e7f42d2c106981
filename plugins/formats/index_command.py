"""``mocapflow index FOLDER -w WORKSPACE``: a folder of takes as a searchable library.

Writes (or rewrites) ``WORKSPACE/library.yaml``, the pipeline of the library: the folder's
motion files (``formats.library``: files added or changed since the last run are read, the
others keep their rows), a clip summary, the end-effector features F_E^15 and a kd-tree
index, the quickstart's search defaults. Then runs it like ``mocapflow run`` (steps whose
inputs are unchanged are skipped) and says which files were added, changed, removed, kept
and rejected (with the reason). ``mocapflow search --db WORKSPACE``, ``mocapflow report``
and ``mocapflow export`` use the workspace. Imports nothing numerical at module level.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

if TYPE_CHECKING:
    from mocapflow.framework.commands import CommandContext

#: the pipeline written for a folder (the quickstart's features and index)
PIPELINE = """\
# The library of a folder of takes, written by `mocapflow index`; run `mocapflow index` again
# after adding, changing or deleting files (only those are read again).
name: library
workspace: .
steps:
  motions:
    uses: formats.library
    with: {{folder: {folder}, fps: {fps}}}
  summary:
    uses: analyses.clip_summary
    input: motions
  fe15:
    uses: features.end_effectors
    input: motions
    with: {{joints: 5}}
  tree:
    uses: indexes.kdtree
    input: fe15
"""
#: how many file names each line of the report lists before "... and N more"
SHOWN = 10


def _names(paths: list[str], folder: Path) -> str:
    def rel(p: str) -> str:
        try:
            return Path(p).relative_to(folder).as_posix()
        except ValueError:
            return p

    shown = [rel(p) for p in paths[:SHOWN]]
    more = f" ... and {len(paths) - SHOWN} more" if len(paths) > SHOWN else ""
    return ", ".join(shown) + more


def _files_table(ws: Path) -> list[dict[str, Any]]:
    p = ws / "motions" / "files.parquet"
    if not p.is_file():
        return []
    import pyarrow.parquet as pq

    return cast("list[dict[str, Any]]", pq.read_table(p).to_pylist())


class IndexCommand:
    """``mocapflow index FOLDER -w WORKSPACE [--fps HZ] [--jobs N]``."""

    name = "index"
    help = "make (or bring up to date) a searchable library of every motion file under a folder"

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        from mocapflow.framework.options import float_at_least, int_at_least

        parser.add_argument("folder", help="folder of takes (BVH, FBX, AMC/ASF, glTF...), read recursively")
        parser.add_argument(
            "--workspace", "-w", required=True, metavar="DIR", help="the library's workspace (made if missing)"
        )
        parser.add_argument(
            "--fps",
            type=float_at_least(0, above=True),
            default=30.0,
            metavar="HZ",
            help="analysis rate every take is resampled to (default 30)",
        )
        parser.add_argument(
            "--jobs", "-j", type=int_at_least(0), default=None, help="worker processes for reading (0 = all cores)"
        )

    @classmethod
    def run(cls, args: argparse.Namespace, ctx: CommandContext) -> int:
        from mocapflow.framework.errors import ConfigError
        from mocapflow.framework.runner import run_pipeline
        from mocapflow.framework.workspace import atomic_path

        folder = Path(args.folder).expanduser().resolve()
        ws = Path(args.workspace).expanduser().resolve()
        if not folder.is_dir():
            raise ConfigError(f"{args.folder}: no such folder")
        if ws == folder or folder in ws.parents:
            raise ConfigError(
                f"--workspace {args.workspace} lies inside {args.folder}: its files would be indexed too; "
                "choose a workspace outside the folder"
            )
        if ws.exists() and not ws.is_dir():
            raise ConfigError(f"--workspace {args.workspace} exists and is not a folder")
        _refuse_other_workspace(ws, args.workspace)
        ws.mkdir(parents=True, exist_ok=True)
        pipeline = ws / "library.yaml"
        text = PIPELINE.format(folder=json.dumps(str(folder)), fps=repr(float(args.fps)))
        if not pipeline.is_file() or pipeline.read_text(encoding="utf-8") != text:
            with atomic_path(pipeline) as tmp:
                tmp.write_text(text, encoding="utf-8")
        before = {r["path"]: r for r in _files_table(ws)}

        def echo(msg: str) -> None:
            print(msg, file=sys.stderr, flush=True)

        echo(f"mocapflow: indexing {folder} into {ws} (pipeline {pipeline})")
        reports = run_pipeline(pipeline, workspace=ws, jobs=args.jobs, pm=ctx.plugin_manager, echo=echo)
        after = _files_table(ws)
        by = {s: [r["path"] for r in after if r["status"] == s] for s in ("added", "changed", "unchanged")}
        removed = sorted(set(before) - {r["path"] for r in after})
        motions = next((r for r in reports if r.step_id == "motions"), None)
        summary = (motions.summary or {}) if motions is not None and motions.status == "computed" else {}
        if motions is not None and motions.status != "computed":  # nothing moved under the folder
            by = {"added": [], "changed": [], "unchanged": [r["path"] for r in after if r["status"] != "unsupported"]}
        clips = summary.get("clips", len([r for r in after if not r["rejected"]]))
        print(
            f"library {args.workspace}: {clips} clips from {args.folder}: {len(by['added'])} added, "
            f"{len(by['changed'])} changed, {len(removed)} removed, {len(by['unchanged'])} unchanged"
        )
        for what, paths in (("added", by["added"]), ("changed", by["changed"]), ("removed", removed)):
            if paths:
                print(f"  {what}: {_names(paths, folder)}")
        rejects = _rejects(ws)
        if rejects:
            print(f"  {len(rejects)} rejected (the library goes on without them):")
            for r in rejects[:SHOWN]:
                where = f":{r['line']}" if r["line"] else ""
                print(f"    {_names([r['path']], folder)}{where}: {r['message']}")
            if len(rejects) > SHOWN:
                print(f'    ... see mocapflow sql {args.workspace} "SELECT path, message FROM motions_rejects"')
        good = [r["path"] for r in after if not r["rejected"]]
        example = (Path(args.folder) / Path(good[0]).relative_to(folder)).as_posix() if good else "FILE"
        print(f"search it: mocapflow search --db {args.workspace} --query {example}:0s-1s")
        return 0


def _rejects(ws: Path) -> list[dict[str, Any]]:
    p = ws / "motions" / "rejects.parquet"
    if not p.is_file():
        return []
    import pyarrow.parquet as pq

    return cast("list[dict[str, Any]]", pq.read_table(p, columns=["path", "line", "message"]).to_pylist())


def _refuse_other_workspace(ws: Path, given: str) -> None:
    """A workspace another pipeline wrote (its ``motions`` step not a library's) is refused:
    the library's steps would replace some of its steps and leave the rest stale."""
    from mocapflow.framework.errors import ConfigError

    if not ws.is_dir():
        return
    steps = sorted(p.parent.name for p in ws.glob("*/_manifest.json"))
    try:
        component = json.loads((ws / "motions" / "_manifest.json").read_text()).get("component")
    except (OSError, ValueError):
        component = None
    if steps and (component != "formats.library" or not set(steps) <= {"motions", "summary", "fe15", "tree"}):
        raise ConfigError(
            f"--workspace {given} holds the outputs of another pipeline (steps: {', '.join(steps)}); "
            "a library needs a workspace of its own: choose a new folder"
        )
