"""Built-in plugin: the ``mocapflow search`` command (one query against a finished workspace).

Two ways to answer, same output (docs/knn.md, "mocapflow search start-up"):

* in the calling process: :class:`SearchSession` loads what a search needs and nothing more
  (the registries of formats, features, indexes and matchers only; the index memory-mapped;
  the features memory-mapped from the index's ``rows_*.npy`` sidecars, the Parquet table
  decoded only for an index saved without them);
* through a search server (``mocapflow search --db WS --serve``) that holds one session warm
  (modules imported, numba kernels loaded, index and block boxes in memory) and answers on
  the Unix socket ``WS/.search.sock``; a plain ``mocapflow search`` uses it whenever it
  answers (``--no-server``: never), importing nothing numerical itself
  (:mod:`.search_server`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO, cast

if TYPE_CHECKING:
    import pyarrow as pa

    from mocapflow.framework import FeatureSet, Index, Matcher, SearchSpace
    from mocapflow.framework.commands import CommandContext
    from mocapflow.framework.database import MotionDatabase
    from mocapflow.framework.queries import Query
    from mocapflow.framework.registry import Registries

#: the registries a search needs: a query file's reader, the feature set, the index, the matcher
KINDS = ("formats", "features", "indexes", "matchers")
#: matcher parameter -> the option that sets it (for error messages)
_OPTIONS = {"count": "--count", "k": "-k", "min_span": "--min-span", "rank_by": "--rank-by", "paper": "--paper"}


class SearchCommand:
    """``mocapflow search --db WORKSPACE --query FILE[:START-END]``: one query, matches printed.

    Uses a finished workspace (a pipeline with an index step, e.g. ``pipelines/search.yaml``):
    the index, its features dataset and, through its provenance, the feature set and frame
    rate of the database. The query is a motion file (any registered format, resampled to
    the database rate) or the name of a database clip.
    """

    name = "search"
    help = "find the motion segments of a workspace's database most similar to a query"

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        from mocapflow.framework.options import float_at_least, int_at_least

        parser.add_argument("--db", required=True, metavar="WORKSPACE", help="workspace of a run with an index step")
        parser.add_argument(
            "--query",
            metavar="FILE[:START-END]",
            help="motion file or database clip; frames (end exclusive) or seconds ('1s-3s')",
        )
        parser.add_argument("--index", metavar="STEP", help="index step to use when the workspace has several")
        parser.add_argument(
            "--matcher",
            default="search",
            help="matchers.<name>: search (default: certified, exactly sdtw's matches), lng (the lazy "
            "neighbourhood graph), sdtw, logical",
        )
        parser.add_argument("--count", type=int_at_least(1), default=10, help="matches to show (default 10)")
        parser.add_argument(
            "--min-span",
            type=float_at_least(0),
            default=None,
            metavar="F",
            help="drop matches spanning fewer database frames than F x the query (default 0.5; 0: all)",
        )
        parser.add_argument(
            "--rank-by",
            choices=("cost", "normalized"),
            default=None,
            help="rank by accumulated cost (default) or cost per path cell",
        )
        parser.add_argument(
            "--paper",
            action="store_true",
            default=None,
            help="lng: the paper's graph (neighbour cells only, every frame searched, no fallback)",
        )
        parser.add_argument(
            "--mode",
            choices=("fast", "exact"),
            default=None,
            help="search: exact (sDTW's matches) or fast (filter-and-refine, measured recall); default: the matcher's",
        )
        parser.add_argument(
            "--exclude-self",
            choices=("span", "clip", "off"),
            default=None,
            help="a query cut from a database clip: no match overlapping its span widened by half its length "
            "(span, default), none in its clip (clip), or none excluded (off)",
        )
        parser.add_argument("-k", type=int_at_least(1), default=None, help="neighbours per query frame (lng, logical)")
        parser.add_argument("--plot", metavar="PNG", help="write a Fig. 3-style picture of the best match (lng)")
        parser.add_argument("--out", metavar="FILE", help="also write the matches as .csv or .parquet")
        parser.add_argument(
            "--serve",
            action="store_true",
            help="keep the workspace loaded and answer searches on WORKSPACE/.search.sock until "
            "interrupted (or --idle-timeout); later `mocapflow search --db WORKSPACE` calls use it",
        )
        parser.add_argument(
            "--idle-timeout",
            type=float_at_least(0, above=True),
            default=None,
            metavar="SECONDS",
            help="--serve: stop after this long without a request (default: never)",
        )
        parser.add_argument(
            "--server",
            action=argparse.BooleanOptionalAction,
            default=True,
            help="ask the workspace's search server when one answers (default); --no-server: "
            "always search in this process",
        )

    @classmethod
    def run(cls, args: argparse.Namespace, ctx: CommandContext) -> int:
        from mocapflow.framework.errors import ConfigError

        if args.serve:
            from .search_server import serve

            return serve(args, SearchSession)
        if not args.query:
            raise ConfigError("--query is required (except with --serve)")
        if args.server:
            from .search_server import ask

            rc = ask(args)
            if rc is not None:
                return rc
        session = SearchSession(args.db, args.index, registries=ctx.registries(KINDS))
        return session.answer(args, Path.cwd(), sys.stdout, sys.stderr)


class SearchSession:
    """What searches of one workspace share: registries, datasets, the loaded index, clip
    names and the search spaces (with their memoized block boxes); built once, then
    :meth:`answer` runs one query. The server keeps one alive; :meth:`stamp` says when the
    workspace's index, features or motions step was recomputed (then build a new one).

    Parameters
    ----------
    db : str or Path
        Workspace of a run with an index step.
    index_step : str, optional
        Index step to use when the workspace has several.
    entry_points, blocked
        Plugin selection, as the global ``--no-entry-points`` / ``--block`` (when no
        ``registries`` are given: a server process builds its own).
    registries : Registries, optional
        The registries of the command's context (:class:`~mocapflow.framework.commands.CommandContext`).
    """

    def __init__(
        self,
        db: str | Path,
        index_step: str | None = None,
        *,
        entry_points: bool = True,
        blocked: list[str] | tuple[str, ...] = (),
        registries: Registries | None = None,
    ) -> None:
        from mocapflow.framework import load_registries
        from mocapflow.framework.datasets import read_datasets
        from mocapflow.framework.errors import ConfigError
        from mocapflow.framework.queries import upstream

        self.db = Path(db)
        if not self.db.is_dir():
            raise ConfigError(f"--db {db}: the workspace does not exist (run a pipeline with an index step first)")
        self.regs = regs = (
            registries
            if registries is not None
            else load_registries(kinds=KINDS, entry_points=entry_points, blocked=list(blocked))
        )
        datasets = read_datasets(self.db)
        # only numeric kNN indexes can serve a similarity search (not inverted lists)
        known = set(regs.keys())
        indexes = {
            k: d
            for k, d in datasets.items()
            if d.producer_kind == "indexes"
            and d.producer in known
            and getattr(regs.resolve(d.producer), "supports_knn", True)
        }
        if index_step:
            if index_step not in indexes:
                raise ConfigError(f"{db}: no index step {index_step!r} (index steps: {', '.join(indexes) or 'none'})")
            idx = indexes[index_step]
        elif len(indexes) == 1:
            idx = next(iter(indexes.values()))
        else:
            raise ConfigError(
                f"{db}: {'no index step' if not indexes else 'several index steps ' + ', '.join(indexes)}; run a pipeline with one or pick --index"
            )
        fds = upstream(idx, "features")
        mds = upstream(fds, "motions") if fds is not None else None
        if fds is None or mds is None:
            raise ConfigError(f"{db}: cannot trace index {idx.step!r} back to its features and motions")
        self.idx, self.fds, self.mds = idx, fds, mds
        clips = mds.table("clips", columns=["clip_id", "name", "fps", "source_fps", "source_frames", "path"])
        self.names = dict(zip(clips["clip_id"].to_pylist(), clips["name"].to_pylist(), strict=True))
        #: clip id -> (database fps, source fps, source frames): the table's units (in_source_units)
        self.rates = {r["clip_id"]: (r["fps"], r["source_fps"], r["source_frames"]) for r in clips.to_pylist()}
        self.paths = {r["path"]: r["clip_id"] for r in clips.select(["clip_id", "path"]).to_pylist() if r["path"]}
        self.fps = float(clips["fps"][0].as_py()) if clips.num_rows else None
        self._stamp = self.stamp()
        self._index: Any = None
        self._feature_set: FeatureSet | None = None
        self._mdb: MotionDatabase | None = None
        self._spaces: dict[tuple[bool, bool], SearchSpace] = {}

    def stamp(self) -> tuple[Any, ...]:
        """``(mtime_ns, size)`` of the manifests of the index, features and motions steps."""
        out: list[tuple[int, int, int] | None] = []
        for ds in (self.idx, self.fds, self.mds):
            try:
                st = (ds.path / "_manifest.json").stat()
                out.append((st.st_mtime_ns, st.st_size, st.st_ino))
            except OSError:
                out.append(None)
        return tuple(out)

    def is_stale(self) -> bool:
        return self.stamp() != self._stamp

    def index(self) -> Index:
        """The persisted index, loaded once (memory-mapped by the index class, no rebuild)."""
        if self._index is None:
            self._index = self.idx.index(self.regs)
        return cast("Index", self._index)

    def space(self, matcher: Matcher) -> SearchSpace:
        """The matcher's search space (the core's :func:`~mocapflow.framework.queries.search_space`
        over the loaded index), built once per (index, features) need."""
        from mocapflow.framework.queries import MatchInputs, search_space

        key = (bool(matcher.needs_index), bool(matcher.uses_features()))
        if key not in self._spaces:
            inputs = MatchInputs(self.idx, self.fds, self.mds)
            self._spaces[key] = search_space(matcher, inputs, self.regs, index=self.index())
        return self._spaces[key]

    def feature_set(self) -> FeatureSet:
        if self._feature_set is None:
            from mocapflow.framework.queries import feature_set_of

            self._feature_set = feature_set_of(self.fds, self.regs)
        return self._feature_set

    def matcher(self, args: argparse.Namespace) -> Matcher:
        """The matcher of ``args`` (``--matcher`` and its options; ``lng`` is the graph)."""
        from mocapflow.framework.errors import ConfigError

        matcher_cls = self.regs.resolve(f"matchers.{args.matcher}")
        fields = matcher_cls.Params.model_fields
        params = {"count": args.count, **({"exact": False} if "exact" in fields else {})}
        for key, val in (
            ("k", args.k),
            ("min_span", args.min_span),
            ("rank_by", args.rank_by),
            ("paper", getattr(args, "paper", None)),
            ("mode", getattr(args, "mode", None)),
            ("exclude_self", getattr(args, "exclude_self", None)),
        ):
            if val is not None:
                if key not in fields:
                    raise ConfigError(f"matchers.{args.matcher} has no parameter {key!r}")
                params[key] = val
        try:  # validated here, where pydantic's error still says which option: exit 2 naming it
            matcher_cls.Params.model_validate(params)
        except ValueError as exc:
            from mocapflow.framework.options import options_error

            raise options_error(exc, _OPTIONS, f"matchers.{args.matcher}") from None
        return cast("Matcher", matcher_cls(params))

    def query(self, text: str, cwd: Path) -> Query:
        """The :class:`~mocapflow.framework.queries.Query` of ``--query`` (files relative to ``cwd``)."""
        from mocapflow.framework.database import MotionDatabase
        from mocapflow.framework.matching import parse_query_spec
        from mocapflow.framework.queries import motion_queries

        spec = parse_query_spec(text)

        def resolve(p: str) -> Path:
            return Path(cwd) / Path(p).expanduser()

        if resolve(spec.source).is_file():
            mdb = MotionDatabase([])  # a query file needs only the database's frame rate, not its clips
        else:
            if self._mdb is None:
                self._mdb = self.mds.motions()
            mdb = self._mdb
        return motion_queries([spec], mdb, self.feature_set(), self.regs, resolve, what="--query", fps=self.fps)[0]

    def answer(self, args: argparse.Namespace, cwd: Path, out: TextIO, err: TextIO) -> int:
        """Run the search of ``args`` and print its matches to ``out`` (notes to ``err``)."""
        from mocapflow.framework.errors import ConfigError
        from mocapflow.framework.matching import in_source_units, matches_table
        from mocapflow.framework.output_paths import refuse_dataset_path
        from mocapflow.framework.queries import match_query

        # refused before the work, also when a server answers for a client (its cwd)
        ws: list[str | Path] = [self.db] if getattr(self, "db", None) is not None else []
        out_path = (
            refuse_dataset_path(Path(cwd) / Path(args.out).expanduser(), "--out", workspaces=ws) if args.out else None
        )
        plot_path = (
            refuse_dataset_path(Path(cwd) / Path(args.plot).expanduser(), "--plot", workspaces=ws)
            if args.plot
            else None
        )
        matcher = self.matcher(args)
        space = self.space(matcher)
        query = self.query(args.query, cwd)
        own = query.clip_id
        if own < 0:  # a query file that is one of the database's takes
            own = self.paths.get(str((Path(cwd) / parse_source(args.query)).resolve()), -1)
        found = match_query(matcher, query, space, own)
        res, rows = found.matches, found.excluded
        table = in_source_units(matches_table([0], [res], space), self.rates)
        names = self.names
        mode_note = f" ({matcher.params.mode})" if hasattr(matcher.params, "mode") else ""
        print(
            f"query {query.name} ({len(query.features)} frames at {self.fps or 0:g} fps), {matcher.key()}{mode_note} on "
            f"{self.idx.step!r} ({space.n_rows} frames): {len(res)} matches"
            + (" (its own span excluded)" if rows else "")
            + (f": {found.reason}" if found.reason else ""),
            file=out,
        )
        # frames of each source file at its own rate (fps), and seconds from the take's start
        print(
            f"{'rank':>4}  {'clip':<32} {'fps':>6} {'start':>7} {'end':>7} {'start s':>8} {'dur s':>6} "
            f"{'cost':>10} {'per cell':>9}",
            file=out,
        )
        for row in table.select(
            ["rank", "clip_id", "fps", "start_frame", "end_frame", "start_s", "end_s", "cost", "cost_normalized"]
        ).to_pylist():
            print(
                f"{row['rank']:>4}  {names.get(row['clip_id'], row['clip_id'])!s:<32.32} {row['fps']:>6.4g} "
                f"{row['start_frame']:>7} {row['end_frame']:>7} {row['start_s']:>8.2f} "
                f"{row['end_s'] - row['start_s']:>6.2f} {row['cost']:>10.4g} {row['cost_normalized']:>9.4g}",
                file=out,
            )
        if out_path is not None:
            import pyarrow as pa

            table = table.add_column(
                3, "clip", pa.array([names.get(c) for c in table["clip_id"].to_pylist()], pa.string())
            )
            write_atomic(table, out_path)
        if plot_path is not None:
            if args.matcher not in ("search", "lng") or not len(res):
                raise ConfigError("--plot draws the lazy neighborhood graph of the best match: --matcher search or lng")
            from .graph import K, build_graph, graph_options
            from .plots import plot_neighborhood

            paper = bool(getattr(matcher.params, "paper", False))
            o = graph_options(paper, getattr(matcher.params, "k", K))
            graph = build_graph(query.features, space, k=o["k"], propagate=o["propagate"], gaps=o["gaps"])
            plot_neighborhood(graph, res, space, plot_path, title=f"{query.name}: best match, cost {res.cost[0]:.3g}")
            print(f"wrote {args.plot}", file=err)
        return 0


def write_atomic(table: pa.Table, out: Path) -> None:
    """Write ``table`` as ``.parquet`` (with paths) or CSV (without), creating the folder; atomic (temp + rename)."""
    import os
    import tempfile

    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", dir=out.parent)
    os.close(fd)
    try:
        if out.suffix == ".parquet":
            import pyarrow.parquet as pq

            pq.write_table(table, tmp)
        else:
            import pyarrow as pa
            import pyarrow.csv as pcsv

            nested = [c for c in table.column_names if pa.types.is_nested(table.schema.field(c).type)]
            pcsv.write_csv(table.drop_columns(nested), tmp)
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def parse_source(text: str) -> Path:
    """The file or clip part of ``--query SOURCE[:START-END]``."""
    from mocapflow.framework.matching import parse_query_spec

    return Path(parse_query_spec(text).source).expanduser()
