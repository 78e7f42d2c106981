"""Built-in plugin: the global matchers and the ``mocapflow search`` command."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


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
        parser.add_argument("--db", required=True, metavar="WORKSPACE", help="workspace of a run with an index step")
        parser.add_argument("--query", required=True, metavar="FILE[:START-END]",
                            help="motion file or database clip; frames (end exclusive) or seconds ('1s-3s')")
        parser.add_argument("--index", metavar="STEP", help="index step to use when the workspace has several")
        parser.add_argument("--matcher", default="lng", help="matchers.<name>: lng (default), sdtw, logical")
        parser.add_argument("--count", type=int, default=10, help="matches to show (default 10)")
        parser.add_argument("--min-span", type=float, default=None, metavar="F",
                            help="drop matches spanning fewer database frames than F x the query (default 0.5; 0: all)")
        parser.add_argument("--rank-by", choices=("cost", "normalized"), default=None,
                            help="rank by accumulated cost (default) or cost per path cell")
        parser.add_argument("--exact", action=argparse.BooleanOptionalAction, default=None,
                            help="return exactly subsequence DTW's matches (lng: a certified pruned DP, identical to "
                                 "sdtw; the default of lng); --no-exact: lng answers from its neighborhood graph")
        parser.add_argument("--gaps", type=int, default=None, metavar="G",
                            help="lng --no-exact: query frames a path may cross without a kNN cell (default: the matcher's, 32; 0: the paper's graph)")
        parser.add_argument("--propagate", type=int, default=None, metavar="N",
                            help="lng --no-exact: search the index every N-th query frame only, propagate the sets in between")
        parser.add_argument("-k", type=int, default=None, help="neighbours per query frame (lng, logical)")
        parser.add_argument("--radius", type=float, default=None, help="kNN search radius (lng, logical)")
        parser.add_argument("--plot", metavar="PNG", help="write a Fig. 3-style picture of the best match (lng)")
        parser.add_argument("--out", metavar="FILE", help="also write the matches as .csv or .parquet")

    @classmethod
    def run(cls, args: argparse.Namespace) -> int:
        import pyarrow as pa

        from mocapflow.framework import MotionDatabase, load_registries
        from mocapflow.framework.datasets import read_datasets
        from mocapflow.framework.errors import ConfigError

        from mocapflow.framework.matching import matches_table
        from mocapflow.framework.queries import feature_set_of, motion_queries, parse_query_spec, upstream

        if not Path(args.db).is_dir():
            raise ConfigError(f"--db {args.db}: the workspace does not exist (run a pipeline with an index step first)")
        # the global --no-entry-points / --block apply here too
        regs = load_registries(entry_points=not getattr(args, "no_entry_points", False),
                               blocked=list(getattr(args, "block", None) or []))
        datasets = read_datasets(args.db)
        # only numeric kNN indexes can serve a similarity search (not inverted lists)
        indexes = {k: d for k, d in datasets.items() if d.producer_kind == "indexes"
                   and d.producer in regs.keys() and getattr(regs.resolve(d.producer), "supports_knn", True)}
        if args.index:
            if args.index not in indexes:
                raise ConfigError(f"{args.db}: no index step {args.index!r} (index steps: {', '.join(indexes) or 'none'})")
            idx = indexes[args.index]
        elif len(indexes) == 1:
            idx = next(iter(indexes.values()))
        else:
            raise ConfigError(f"{args.db}: {'no index step' if not indexes else 'several index steps ' + ', '.join(indexes)}; run a pipeline with one or pick --index")
        fds = upstream(idx, "features")
        mds = upstream(fds, "motions") if fds is not None else None
        if fds is None or mds is None:
            raise ConfigError(f"{args.db}: cannot trace index {idx.step!r} back to its features and motions")
        matcher_cls = regs.resolve(f"matchers.{args.matcher}")
        fields = matcher_cls.Params.model_fields
        params = {"count": args.count}
        if args.exact and args.matcher == "sdtw":
            args.exact = None  # sdtw is exact already
        for key, val in (("k", args.k), ("radius", args.radius), ("min_span", args.min_span), ("rank_by", args.rank_by),
                         ("gaps", args.gaps), ("propagate", args.propagate), ("exact", args.exact)):
            if val is not None:
                if key not in fields:
                    raise ConfigError(f"matchers.{args.matcher} has no parameter {key!r}")
                params[key] = val
        matcher = matcher_cls(params)
        space = matcher.search_space({"database": idx, "features": fds}, regs)
        spec = parse_query_spec(args.query)
        clips = mds.table("clips", columns=["clip_id", "name", "fps"])
        # a query file needs only the database's frame rate, not its clips
        mdb = MotionDatabase([]) if Path(spec.source).expanduser().is_file() else mds.motions()
        fps = float(clips["fps"][0].as_py()) if clips.num_rows else None
        query = motion_queries([spec], mdb, feature_set_of(fds, regs), regs, lambda p: Path(p).expanduser(),
                               what="--query", fps=fps)[0]
        res = matcher.match(query.features, space)
        table = matches_table([0], [res], space)
        names = dict(zip(clips["clip_id"].to_pylist(), clips["name"].to_pylist()))
        print(f"query {query.name} ({len(query.features)} frames), {matcher.key()} on {idx.step!r} "
              f"({space.n_rows} frames): {len(res)} matches")
        print(f"{'rank':>4}  {'clip':<32} {'start':>6} {'end':>6} {'cost':>10} {'per cell':>9}")
        for row in table.select(["rank", "clip_id", "start_frame", "end_frame", "cost", "cost_normalized"]).to_pylist():
            print(f"{row['rank']:>4}  {names.get(row['clip_id'], row['clip_id'])!s:<32.32} {row['start_frame']:>6} "
                  f"{row['end_frame']:>6} {row['cost']:>10.4g} {row['cost_normalized']:>9.4g}")
        if args.out:
            table = table.append_column("clip", pa.array([names.get(c) for c in table["clip_id"].to_pylist()], pa.string()))
            write_atomic(table, Path(args.out))
        if args.plot:
            if args.matcher != "lng" or not len(res):
                raise ConfigError("--plot draws the lazy neighborhood graph of the best match: use --matcher lng")
            from .graph import build_graph
            from .plots import plot_neighborhood

            p = matcher.params
            graph = build_graph(query.features, space, k=p.k, radius=p.radius, eps=p.eps, propagate=p.propagate,
                                gaps=p.gaps)
            plot_neighborhood(graph, res, space, args.plot, title=f"{query.name}: best match, cost {res.cost[0]:.3g}")
            print(f"wrote {args.plot}", file=sys.stderr)
        return 0


def write_atomic(table, out: Path) -> None:
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
            import pyarrow.csv as pcsv

            pcsv.write_csv(table.drop_columns(["path"]), tmp)
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
