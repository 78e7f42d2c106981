"""Global search at library scale: queries from performers the library does not hold.

    python benchmarks/search_scale.py --sizes 1000000 3000000     # libraries of 1 M and 3 M rows
    python benchmarks/search_scale.py --sizes 10000000 --queries 6
    python benchmarks/search_scale.py --quick                      # the bundled takes, a 60 k-row library

The library (``benchmarks/corpus.py``, :func:`build_library`) is grown from ../shared/data with copies that no two
are alike (mirroring, bone-length and time scaling, style offsets, noise), streamed to a
memory-mapped F_E^15 table; a quarter of the performers (``--fold``) is held out entirely and
the queries are random 30-, 64- and 90-frame segments of their takes. Each query runs, in the
same process and one thread: subsequence DTW over every row (the baseline), the certified
search (``mode: exact``, must equal sDTW) and the fast mode (``mode: fast``). Printed per
query length: median ms per query, the ratio of medians sDTW / method, the recall of sDTW's
top-10 (a match of sDTW's counts as found when a returned match overlaps its rows) as mean and
minimum over the queries, and whether the exact mode returned sDTW's matches. ``--threads 2``
adds the all-core rows: sDTW and both modes with numba threads over the database's blocks.
First, per query length, the exact mode's first query on a new search space (which builds
the space's block boxes and subspace cells) against the same query once more (warm).
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from pathlib import Path

import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from corpus import DATA, REPO, build_library, held_out, load_takes, open_library, subjects_of

from mocapflow.framework.matching import SearchSpace
from mocapflow.plugins.similarity.knn.end_effectors import EndEffectorFeatures
from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex
from mocapflow.plugins.similarity.search.certified import ExactStats, certified_sdtw
from mocapflow.plugins.similarity.search.fast import FastSettings, fast_sdtw
from mocapflow.plugins.similarity.search.sdtw import subsequence_dtw

FAST = {
    "fast (default)": FastSettings(),
    "fast k64 f12": FastSettings(k=64, frames=12),
}
#: ``--wide``: more neighbours per frame (recall against time at scale)
WIDE = {"fast k256 f24": FastSettings(k=256), "fast k512 f24": FastSettings(k=512)}


def recall(res, ref) -> float:
    """Share of ``ref``'s matches overlapped by a match of ``res`` (rows ``[start, end)``)."""
    if not len(ref):
        return 1.0
    found = 0
    for s, e in zip(ref.start.tolist(), ref.end.tolist(), strict=True):
        found += bool(np.any((res.start < e) & (res.end > s)))
    return found / len(ref)


def queries_of(files, motions, hidden, lengths, per_length, rng) -> dict[int, list[np.ndarray]]:
    fe = EndEffectorFeatures(joints=5)
    subj = subjects_of(files)
    feats = [fe.transform_motion(motions[c]) for c in range(len(files)) if subj[c] in hidden]
    out = {}
    for m in lengths:
        pool = [f for f in feats if len(f) >= m]
        qs = []
        for _ in range(per_length):
            f = pool[int(rng.integers(len(pool)))]
            s = int(rng.integers(0, len(f) - m + 1))
            qs.append(np.ascontiguousarray(f[s : s + m]))
        out[m] = qs
    return out


def timed(fn, *a, **kw):
    t = time.perf_counter()
    r = fn(*a, **kw)
    return r, time.perf_counter() - t


def run_size(n: int, args, base, rng) -> None:
    if args.wide:
        FAST.update(WIDE)
    files, motions = base
    t0 = time.perf_counter()
    path = build_library(n, fold=args.fold, base=base, cache=args.cache)
    lib = open_library(path)
    t_lib = time.perf_counter() - t0
    t0 = time.perf_counter()
    index = KDTreeIndex(method="kdtree", workers=1).build(lib.features)
    t_index = time.perf_counter() - t0
    space = SearchSpace(lib.clip_id, lib.frame, index, lib.features)
    hidden = held_out(subjects_of(files), args.fold)
    qs = queries_of(files, motions, hidden, args.lengths, args.queries, rng)
    numba.set_num_threads(args.threads)
    if args.threads > 1:
        subsequence_dtw(qs[args.lengths[0]][0], space)  # the parallel kernel, compiled outside the timings
    numba.set_num_threads(1)
    for m in args.lengths:  # compile / load kernels, block boxes, subspace cells: outside the timings
        q0 = qs[m][0]
        if not args.wide:
            certified_sdtw(q0, space)
        for cfg in FAST.values():
            fast_sdtw(q0, space, exact_search=certified_sdtw, settings=cfg)
    subsequence_dtw(q0[:8], space, count=2)
    print(
        f"\n{n:,} rows ({len(np.unique(lib.source))} source takes, {lib.clip_id[-1] + 1:,} copies; held out: "
        f"{', '.join(sorted(hidden))}); library {t_lib:.0f} s, kd-tree {t_index:.0f} s; "
        f"peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB; load {os.getloadavg()[0]:.2f}"
    )
    print(
        f"  {'query':>5} {'method':<22} {'p50 ms':>9} {'sDTW/this':>9} {'recall':>7} {'min':>5} {'identical':>9} {'DP rows':>8} {'fallback':>8}"
    )
    for m in args.lengths:  # the per-space structures (block boxes, subspace cells) of a new space
        for th in sorted({1, args.threads}):
            numba.set_num_threads(th)
            fresh = SearchSpace(lib.clip_id, lib.frame, index, lib.features)
            _, first = timed(certified_sdtw, qs[m][0], fresh)
            _, warm = timed(certified_sdtw, qs[m][0], fresh)
            print(
                f"  {m:>5} exact, first query on a fresh space ({th} thread{'s' * (th > 1)}): {first * 1e3:.0f} ms, "
                f"warm {warm * 1e3:.0f} ms: {first / warm:.1f}x"
            )
        numba.set_num_threads(1)
    for m in args.lengths:
        t_ref, rows = [], {}
        for q in qs[m]:
            ref, t = timed(subsequence_dtw, q, space)
            t_ref.append(t)
            methods = {} if args.wide else {"exact (certified)": lambda q, st: certified_sdtw(q, space, stats=st)}
            methods.update(
                {
                    name: (lambda q, st, c=c: fast_sdtw(q, space, exact_search=certified_sdtw, settings=c, stats=st))
                    for name, c in FAST.items()
                }
            )
            if args.threads > 1:  # the same three on all cores (numba threads over the database's clips)
                methods["sDTW, all cores"] = lambda q, st: subsequence_dtw(q, space)
                methods["exact, all cores"] = methods["exact (certified)"]
                methods["fast, all cores"] = lambda q, st: fast_sdtw(q, space, exact_search=certified_sdtw, stats=st)
            for name, fn in methods.items():
                st = ExactStats()
                numba.set_num_threads(args.threads if name.endswith("all cores") else 1)
                res, t = timed(fn, q, st)
                r = rows.setdefault(name, {"t": [], "rec": [], "same": [], "cols": [], "fb": 0})
                r["cols"].append(st.columns)
                r["fb"] += int(st.retried and name.startswith("fast"))
                r["t"].append(t)
                r["rec"].append(recall(res, ref))
                r["same"].append(np.array_equal(res.end, ref.end) and np.array_equal(res.cost, ref.cost))
        tr = float(np.median(t_ref))
        print(f"  {m:>5} {'sDTW (baseline)':<22} {tr * 1e3:>9.1f} {1.0:>9.1f}")
        for name, r in rows.items():
            t = float(np.median(r["t"]))
            print(
                f"  {m:>5} {name:<22} {t * 1e3:>9.2f} {tr / t:>9.1f} {np.mean(r['rec']):>7.3f} {min(r['rec']):>5.2f} "
                f"{str(all(r['same'])):>9} {np.median(r['cols']):>8.0f} {r['fb']:>8d}"
            )
    sys.stdout.flush()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the bundled takes, a 60,000-row library, 2 queries")
    ap.add_argument("--sizes", type=int, nargs="*", default=[1_000_000])
    ap.add_argument("--lengths", type=int, nargs="*", default=[30, 64, 90])
    ap.add_argument("--queries", type=int, default=8, help="queries per length")
    ap.add_argument("--fold", type=int, default=0, help="which quarter of the performers is held out (0-3)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--wide", action="store_true", help="the fast mode with 256 and 512 neighbours too, no exact mode")
    ap.add_argument("--threads", type=int, default=1, help="also run sDTW and both modes on this many numba threads")
    ap.add_argument("--cache", type=Path, default=None, help="library cache folder (default: the corpus cache)")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    print(f"global search at scale; F_E^15; kd-tree; one thread; {os.cpu_count()} cores")
    if args.quick:
        import tempfile

        files = sorted((REPO / "examples" / "data" / "cmu").glob("*/*.amc"))
        base = load_takes(30.0, None, files)
        args.sizes, args.queries, args.lengths = [60_000], 2, [30, 64]
        with tempfile.TemporaryDirectory(prefix="mocapflow-library-") as tmp:
            args.cache = Path(tmp)
            run_size(60_000, args, base, rng)
        return 0
    if not DATA.is_dir():
        raise SystemExit(f"the corpus is not at {DATA} (set MOCAPFLOW_DATA)")
    base = load_takes(30.0, DATA)
    if args.cache is None:
        from corpus import CACHE

        args.cache = CACHE
    for n in args.sizes:
        run_size(n, args, base, rng)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
