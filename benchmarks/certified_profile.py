"""Where a certified query's time goes, on exactly the issue command's queries (issue 13).

    python benchmarks/certified_profile.py                         # 380,813 and 1,038,388 rows
    python benchmarks/certified_profile.py --sizes 1038388 --lengths 90
    python benchmarks/certified_profile.py --quick                 # 60,000 rows: a smoke run

The queries are ``benchmarks/matching.py``'s (``--seed``, 4 per length; its random stream is
replayed through every size, so ``--sizes 1038388`` still gets the 1 M-row queries of the
two-size run). Per query: sDTW's time, the default certified search's (median of 5 runs,
wall, as ``matching.py`` times it) and its parts, each the wall time inside one function
(the parts nest: ``seeds`` holds its own ``knn``, ``dp`` and ``select`` calls):

* ``seeds`` — :func:`exact._seed_tau` (the threshold from the windows around the index's
  neighbours of a few query frames); ``knn`` the index queries in it;
* ``box`` / ``sub`` — the coarse levels' box and local-subspace cells;
* ``dp`` — every fine DP call (the seeds' windows and the pass); ``select`` the greedy
  selections; ``path`` the matches' warping paths; ``alive`` the runs of blocks kept.

Also printed: ``tau``, the blocks in play per level below the first, the pass's fine DP rows
and the seeds' rows, and (``--seed-windows``) the share of the seeds' window rows that lie in
windows whose coarsest-level bound is <= ``tau`` (what ordering or pruning the windows by that
bound, which needs no ``tau``, could save). No assertions: the figures are the output.
"""
from __future__ import annotations

import argparse
import functools
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

PARTS = {"seeds": ("exact", "_seed_tau"), "knn": ("kdtree", "KDTreeIndex.query"),
         "box": ("coarse", "coarse_bounds"), "sub": ("coarse", "subspace_bounds"),
         "dp": ("dtw", "sdtw_ranges_compact"), "select": ("exact", "select_matches"),
         "path": ("dtw", "dtw_window_path"), "alive": ("coarse", "alive_runs")}


def instrument(spent: dict) -> None:
    """Wrap each part's function so that its wall time accumulates in ``spent[part]``."""
    import mocapflow.plugins.similarity.search._coarse_kernels as coarse
    import mocapflow.plugins.similarity.search._dtw_kernels as dtw
    import mocapflow.plugins.similarity.search.exact as exact
    import mocapflow.plugins.similarity.knn.kdtree as kdtree

    modules = {"exact": exact, "coarse": coarse, "dtw": dtw, "kdtree": kdtree}
    for part, (mod, name) in PARTS.items():
        owner = modules[mod]
        if "." in name:
            cls, name = name.split(".")
            owner = getattr(owner, cls)
        fn = getattr(owner, name)

        # functools.wraps keeps the signature: exact._query_params inspects the index's query
        @functools.wraps(fn)
        def timed(*a, _fn=fn, _part=part, **kw):
            t = time.perf_counter()
            try:
                return _fn(*a, **kw)
            finally:
                spent[_part] = spent.get(_part, 0.0) + time.perf_counter() - t
        setattr(owner, name, timed)


def seed_window_share(q, space, tau) -> float:
    """Share of the seed windows' rows in windows whose coarsest-level bound is <= ``tau``."""
    import mocapflow.plugins.similarity.search._dtw_kernels as dtw
    import mocapflow.plugins.similarity.search.exact as exact
    from mocapflow.plugins.similarity.search.matcher_base import block_boxes_of

    calls = []
    fn = dtw.sdtw_ranges_compact
    dtw.sdtw_ranges_compact = lambda *a: (calls.append(a[3]), fn(*a))[1]
    try:
        exact._seed_tau(q, np.ascontiguousarray(q.T), space, 10, None, "cost", exact.min_frames_of(0.5, len(q)),
                        exact.ExactStats())
    finally:
        dtw.sdtw_ranges_compact = fn
    windows = calls[-1]
    level = block_boxes_of(space, exact.LEVELS[0]) + (exact.LEVELS[0], 0)
    lb = exact._level_bounds(np.ascontiguousarray(q.T), space, level, np.array([[0, len(level[1])]], np.int64))
    starts = level[0][:-1]
    first = np.searchsorted(starts, windows[:, 0], side="right") - 1
    last = np.searchsorted(starts, windows[:, 1] - 1, side="right") - 1
    low = np.array([lb[a : b + 1].min() for a, b in zip(first, last)])
    rows = windows[:, 1] - windows[:, 0]
    return float(rows[low <= tau].sum() / max(rows.sum(), 1))


def main(argv=None) -> int:
    import matching as mt

    import mocapflow.plugins.similarity.search.exact as exact

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="60,000 rows, 2 queries per length")
    ap.add_argument("--sizes", type=int, nargs="*", default=None)
    ap.add_argument("--lengths", type=int, nargs="*", default=[30, 64, 90])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--seed-windows", action="store_true", help="the seed windows' rows under tau at the top level")
    args = ap.parse_args(argv)
    all_sizes = [60_000] if args.quick else [380_813, 1_038_388]
    sizes = args.sizes or all_sizes
    n_q = 2 if args.quick else 4
    spent: dict = {}
    instrument(spent)
    rng = np.random.default_rng(args.seed)
    for n in all_sizes:
        if n > max(sizes):
            break
        space = mt.database_space(n)
        mt.random_queries(space, 8, 1, rng)  # matching.py's warm-up query
        for m in (30, 64, 90):
            qs = mt.random_queries(space, m, n_q, rng)
            if n not in sizes or m not in args.lengths:
                continue
            for q in qs:
                exact.certified_sdtw(q[:8], space, count=3, subspace_from=0)  # compile, cells, outside timings
                _, t_sdtw = mt.timed(mt.subsequence_dtw, q, space, count=10)
                runs = []
                for _ in range(args.runs):
                    spent.clear()
                    st = exact.ExactStats()
                    t = time.perf_counter()
                    exact.certified_sdtw(q, space, count=10, stats=st)
                    runs.append((time.perf_counter() - t, dict(spent), st))
                runs.sort(key=lambda r: r[0])
                t, parts, st = runs[len(runs) // 2]
                print(f"{n:>9,} rows {m:>2} frames: sDTW {t_sdtw * 1e3:6.1f} ms, certified {t * 1e3:6.2f} ms "
                      f"({t_sdtw / t:5.1f}x), tau {st.tau:6.2f} | "
                      + " ".join(f"{p} {parts.get(p, 0.0) * 1e3:.2f}" for p in PARTS)
                      + f" | blocks in play {st.level_blocks}, fine rows {st.columns:,}, seed rows {st.guess_columns:,}"
                      + (f", seed window rows under tau {seed_window_share(q, space, st.tau):.0%}"
                         if args.seed_windows else ""), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
