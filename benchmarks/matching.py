"""LNG end to end (kNN + graph + path) against exact subsequence DTW (Krüger et al. 2010, §4).

    python benchmarks/matching.py            # 380,813 and 1,038,388-frame databases
    python benchmarks/matching.py --quick    # a 60,000-frame database, few queries

Databases come from ``benchmarks/corpus.py`` (the real CMU + HDM05 corpus grown by
realistic augmentation), features are F_E^15 (``features.end_effectors``, joints 5), the
index is ``indexes.kdtree`` (kd-tree method, one thread, like the paper's ANN runs).
Queries are random database segments of 30, 64 and 90 frames (1 s, ~2 s, 3 s at 30 Hz).
Printed per database and query length: median milliseconds per query of

* LNG with exact kNN (k = 256 and 64), split into kNN search and graph + path search
  (microseconds per query frame);
* LNG with ε-approximate kNN (ε = 0.1, 0.5), and with propagated neighbour sets (index
  searched every 8th query frame, or only for the first: ``matchers.lng`` ``propagate``),
  with the fraction of queries whose best match is the exact-kNN LNG's and the fraction of
  the exact-kNN LNG's top-10 alignments found again (the "recall" of the approximation; the
  paper reports ≈ 99 % of the alignments for ε = 0.5 on windowed feature sets);
* our subsequence DTW (numba, one thread; cells per second);
* dtaidistance's ``subsequence_alignment`` (C, ``use_c=True``, penalty 0) on the same
  data, when installed (``pip install dtaidistance``; benchmark only), on a few queries;

and the ratios sDTW / LNG. No assertions: the figures are the output.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from corpus import augmented_database

from mocapflow.plugins.similarity.knn.end_effectors import EndEffectorFeatures
from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex
from mocapflow.plugins.similarity.search._lng_kernels import lng_forward
from mocapflow.plugins.similarity.search.lng import lazy_neighborhood_graph
from mocapflow.plugins.similarity.search.graph import NeighborhoodGraph, neighbor_sets
from mocapflow.framework.matching import SearchSpace
from mocapflow.plugins.similarity.search.sdtw import subsequence_dtw


def database_space(n_frames: int, echo=print, names: list | None = None) -> SearchSpace:
    t0 = time.perf_counter()
    db = augmented_database(n_frames, fps=30)
    t1 = time.perf_counter()
    x = EndEffectorFeatures(joints=5).transform(db)
    t2 = time.perf_counter()
    index = KDTreeIndex(method="kdtree", workers=1).build(x)
    t3 = time.perf_counter()
    clip_id, frame = db.frame_ids
    if names is not None:  # each clip's source clip (augmented copies are named <source>[_mirrored][_v<n>])
        import re

        names.extend(re.sub(r"(_mirrored)?(_v\d+)?$", "", m.name) for m in db)
    echo(f"database {n_frames:,} frames, {db.n_clips} clips: load {t1 - t0:.1f} s, F_E^15 {t2 - t1:.1f} s, "
         f"kd-tree build {t3 - t2:.1f} s")
    return SearchSpace(clip_id, frame, index, x)


def random_segments(space: SearchSpace, length: int, count: int, rng: np.random.Generator) -> list[int]:
    """First rows of ``count`` random segments of ``length`` frames lying inside one clip."""
    out: list[int] = []
    while len(out) < count:
        s = int(rng.integers(0, space.n_rows - length))
        if space.clip_id[s] == space.clip_id[s + length - 1] and space.frame[s + length - 1] - space.frame[s] == length - 1:
            out.append(s)
    return out


def random_queries(space: SearchSpace, length: int, count: int, rng: np.random.Generator) -> list[np.ndarray]:
    """``count`` random segments of ``length`` frames lying inside one clip."""
    return [space.features[s : s + length] for s in random_segments(space, length, count, rng)]


def timed(fn, *args, **kwargs):
    t = time.perf_counter()
    r = fn(*args, **kwargs)
    return r, time.perf_counter() - t


def lng_once(q, space, k, eps, propagate=0):
    """(top-10 [(start, end), ...], total seconds, kNN seconds) of one LNG query."""
    t0 = time.perf_counter()
    ids, dist, count = neighbor_sets(q, space.index, k, None, eps, propagate, space)
    t1 = time.perf_counter()
    cost, start, pred, length = lng_forward(ids, dist, count, space.continues)
    res = NeighborhoodGraph(ids, dist, count, cost, start, pred, length).matches(count=10, min_span=0)
    t2 = time.perf_counter()
    return list(zip(res.start.tolist(), res.end.tolist())), t2 - t0, t1 - t0


def matcher_once(q, space, **kw):
    """(top-10 [(start, end), ...], seconds, result) of one ``lazy_neighborhood_graph`` call (matcher defaults +
    ``kw``); with ``levels`` or ``top`` in ``kw``, of :func:`certified_sdtw` with those settings."""
    from mocapflow.plugins.similarity.search import exact

    full_from, exact.FULL_FROM = exact.FULL_FROM, kw.pop("full_from", exact.FULL_FROM)
    try:
        t0 = time.perf_counter()
        if "levels" in kw or "top" in kw or "approx" in kw:
            kw.pop("exact", None)
            st = exact.ExactStats()
            res = exact.certified_sdtw(q, space, count=10, stats=st, **kw)
            res.work = (1.2 * st.coarse_blocks + st.columns + st.guess_columns) / space.n_rows  # of sDTW's cells
        else:
            res = lazy_neighborhood_graph(q, space, count=10, **kw)
    finally:
        exact.FULL_FROM = full_from
    return list(zip(res.start.tolist(), res.end.tolist())), time.perf_counter() - t0, res


def kept(runs, exact) -> tuple[float, float]:
    """Fraction of queries with the exact-kNN LNG's best match, and of its top-10 alignments found."""
    same = [bool(r[0]) and bool(e[0]) and r[0][0] == e[0][0] for r, e in zip(runs, exact)]
    found = [len(set(r[0]) & set(e[0])) / max(len(e[0]), 1) for r, e in zip(runs, exact)]
    return float(np.mean(same)), float(np.mean(found))


def spearman_same_end(runs, ref) -> float:
    """Spearman's rho of sDTW's and the method's costs over sDTW's top-10 ends the method also returns."""
    from scipy.stats import spearmanr

    a, b = [], []
    for r, (e, _) in zip(runs, ref):
        got = {int(x): float(c) for x, c in zip(r[2].end, r[2].cost)}
        for x, c in zip(e.end.tolist(), e.cost.tolist()):
            if x in got:
                a.append(c)
                b.append(got[x])
    return float(spearmanr(a, b).statistic) if len(a) > 2 else float("nan")


def bench_size(space: SearchSpace, lengths, n_queries, n_exact, ks, rng, echo=print, propagate=(8, 1000),
               ann: SearchSpace | None = None, gaps=(), approx=(), certified_only=False) -> None:
    gap_variants = [(f"graph gaps {g}, fill", {"gaps": g, "exact": False}) for g in gaps]
    try:
        from dtaidistance.subsequence.dtw import subsequence_alignment
    except ImportError:
        subsequence_alignment = None
        echo("(dtaidistance not installed: no dtaidistance baseline)")
    # warm the kernels (numba compile) outside the timings
    w = random_queries(space, 8, 1, rng)[0]
    lng_once(w, space, 8, 0.0)
    lng_once(w, space, 8, 0.1)
    lng_once(w, space, 8, 0.0, 4)
    subsequence_dtw(w, SearchSpace(space.clip_id[:500], space.frame[:500], features=space.features[:500]))
    matcher_once(w, space)
    matcher_once(w, space, exact=False)
    for lev in ((256, 32, 8), (128, 16)):
        matcher_once(w, space, levels=lev)
    for m in lengths:
        qs = random_queries(space, m, n_queries, rng)
        ref = [timed(subsequence_dtw, q, space, count=10) for q in qs[:n_exact]]
        t_sdtw = float(np.median([t for _, t in ref]))
        rows = [("sDTW (ours, exact)", t_sdtw, float("nan"), float("nan"), float("nan"), float("nan"))]
        # the matcher as a user gets it (gaps 32, fill, min_span 0.5), and the certified-exact mode,
        # against sDTW's own top-10 (same min_span): alignments found, and identical results
        sd_sets = [list(zip(r.start.tolist(), r.end.tolist())) for r, _ in ref]
        variants = [("matcher default (certified, 512/64/16/4)", {"exact": True}),
                    ("exact, levels 256/32/8", {"exact": True, "levels": (256, 32, 8)}),
                    ("exact, levels 128/16", {"exact": True, "levels": (128, 16)}),
                    ("exact, 1 level, tau from LNG (before)", {"exact": True, "top": 0}),
                    ("graph gaps 32 fill prop 2 (old default)", {"exact": False}),
                    ("graph gaps 32, fill, propagate 0", {"exact": False, "propagate": 0}),
                    ("graph, propagate 8", {"exact": False, "propagate": 8}),
                    ("graph, k=64", {"exact": False, "k": 64})]
        variants += gap_variants
        approx_variants = [(f"bounded approx, eps {e:g}", {"exact": True, "approx": e}) for e in approx]
        if certified_only:
            variants = [variants[0], ("certified exact (work counted)", {"exact": True, "approx": 0.0})]
        variants += approx_variants
        if ann is not None:
            variants += [("default, indexes.hnsw", {"ann": True}), ("graph, indexes.hnsw", {"ann": True, "exact": False})]
        for name, kw in variants:
            sp = ann if kw.pop("ann", False) else space
            runs = [matcher_once(q, sp, **kw) for q in qs[:n_exact]]
            same, found = kept(runs, [(s,) for s in sd_sets])
            found = float(np.mean([len(set(r[0]) & set(e)) / max(len(e), 1) for r, e in zip(runs, sd_sets)]))
            approx_run = kw.get("approx", 0.0) > 0
            if kw.get("exact") and not approx_run:
                ident = all(np.array_equal(r[2].cost, e.cost) and np.array_equal(r[2].end, e.end) for r, (e, _) in zip(runs, ref))
                name += " (identical)" if ident else " (DIFFERS)"
            if hasattr(runs[0][2], "work"):
                w = [1.0 / r[2].work for r in runs]
                name += f" work 1/{np.median(w):.1f}"
            if approx_run:
                name += f" rho {spearman_same_end(runs, ref):.4f}"
            t_all = float(np.median([r[1] for r in runs]))
            rows.append((name + " vs sDTW", t_all, float("nan"), float("nan"), same, found))
        if subsequence_alignment is not None and space.n_rows * (m + 1) * 8 < 4e9:
            runs = []
            for q in qs[: max(1, n_exact // 2)]:
                t = time.perf_counter()
                sa = subsequence_alignment(q.astype(np.float64), space.features.astype(np.float64), penalty=0.0, use_c=True)
                sa.best_match()
                runs.append(time.perf_counter() - t)
                del sa
            rows.append(("dtaidistance subsequence_alignment", float(np.median(runs)), float("nan"), float("nan"), float("nan"),
                         float("nan")))
        for k in ks:
            exact = [lng_once(q, space, k, 0.0) for q in qs]
            variants = [(f"LNG k={k} eps={e:g}", e, 0) for e in (0.0, 0.1, 0.5)]
            variants += [(f"LNG k={k} propagate={p}" + (" (1st frame)" if p >= m else ""), 0.0, p)
                         for p in propagate if p > 0]
            for name, eps, prop in variants:
                runs = exact if eps == 0 and prop == 0 else [lng_once(q, space, k, eps, prop) for q in qs]
                same, found = kept(runs, exact)
                t_all = float(np.median([r[1] for r in runs]))
                t_knn = float(np.median([r[2] for r in runs]))
                rows.append((name, t_all, t_knn, t_all - t_knn, same, found))
        echo(f"  query {m} frames ({len(qs)} LNG / {min(n_exact, len(qs))} sDTW queries); sDTW {m * space.n_rows / t_sdtw / 1e6:.0f} M cells/s; "
             f"load average {open('/proc/loadavg').read().split()[0]}")
        echo(f"    {'method':<62} {'ms/query':>9} {'kNN ms':>8} {'graph us/frame':>15} {'same best':>9} {'top-10 kept':>11} {'sDTW/this':>10}")
        for name, t, tk, tg, same, found in rows:
            echo(f"    {name:<62} {t * 1e3:>9.2f} {tk * 1e3:>8.2f} {tg * 1e6 / m:>15.1f} {same:>9.2f} {found:>11.2f} {t_sdtw / t:>10.1f}")


#: methods of the hidden-source benchmark: label -> certified_sdtw keywords
HIDDEN_METHODS = {
    "default (certified exact)": {},
    "approx 0.15 (chosen LOAO)": {"approx": 0.15},
    "approx 0.5": {"approx": 0.5},
    "approx inf (seed windows only)": {"approx": np.inf},
    "seed windows only, 5 x 20 x count": {"approx": np.inf, "seed_k": 20},
    "certified, levels 512/64/16/4/2": {"levels": (512, 64, 16, 4, 2)},
    "certified, levels 256/32/8/2": {"levels": (256, 32, 8, 2)},
}


def bench_hidden(space: SearchSpace, sources: list, lengths, n_queries, rng, echo=print) -> None:
    """Recall of sDTW's top-10 and Spearman's rho with the query's source clip hidden: every
    augmented copy of the clip the query was cut from is removed from the database (its own kd-tree),
    so only other performances count (issue 13's quality targets, at scale); with the time ratios."""
    from scipy.stats import spearmanr

    from mocapflow.plugins.similarity.search.exact import certified_sdtw

    src = np.asarray(sources)[space.clip_id]
    echo(f"  query's source clip hidden (all its augmented copies); {n_queries} queries per length; "
         f"load average {open('/proc/loadavg').read().split()[0]}")
    echo(f"    {'query':>6} {'method':<36} {'recall':>7} {'rho':>7} {'full':>5} {'work 1/x':>9} {'sDTW/this':>9}")
    for m in lengths:
        stats = {k: {"hit": [], "a": [], "b": [], "t": [], "full": [], "w": []} for k in HIDDEN_METHODS}
        t_ref = []
        for s in random_segments(space, m, n_queries, rng):
            keep = src != src[s]
            sub = SearchSpace(space.clip_id[keep], space.frame[keep],
                              KDTreeIndex(method="kdtree", workers=1).build(space.features[keep]), space.features[keep])
            q = space.features[s : s + m]
            certified_sdtw(q[:8], sub, count=3)  # the sub-space's block boxes, outside the timings
            ref, t = timed(subsequence_dtw, q, sub, count=10)
            t_ref.append(t)
            for name, kw in HIDDEN_METHODS.items():
                from mocapflow.plugins.similarity.search.exact import ExactStats

                st = ExactStats()
                res, t = timed(certified_sdtw, q, sub, count=10, stats=st, **kw)
                r = stats[name]
                r["t"].append(t)
                r["full"].append(len(res) == 10)
                r["w"].append(sub.n_rows / max(1.2 * st.coarse_blocks + st.columns + st.guess_columns, 1))
                got = {int(e): float(c) for e, c in zip(res.end, res.cost)}
                for e, c in zip(ref.end.tolist(), ref.cost.tolist()):
                    r["hit"].append(e in got)
                    if e in got:
                        r["a"].append(c)
                        r["b"].append(got[e])
        for name, r in stats.items():
            rho = spearmanr(r["a"], r["b"]).statistic if len(r["a"]) > 2 else float("nan")
            echo(f"    {m:>4} f {name:<36} {np.mean(r['hit']):>7.3f} {rho:>7.4f} {np.mean(r['full']):>5.2f} "
                 f"{np.median(r['w']):>9.1f} {np.median(t_ref) / np.median(r['t']):>9.1f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one 60,000-frame database, 8 queries per length")
    ap.add_argument("--sizes", type=int, nargs="*", default=None, help="database sizes in frames")
    ap.add_argument("--queries", type=int, default=None, help="LNG queries per length (default 32; quick 8)")
    ap.add_argument("--exact", type=int, default=None, help="sDTW queries per length (default 6; quick 3)")
    ap.add_argument("-k", type=int, nargs="*", default=[256, 64], help="neighbours per query frame (paper: 256)")
    ap.add_argument("--propagate", type=int, nargs="*", default=[8, 1000],
                    help="LNG rows with propagated neighbour sets: index search every N query frames (>= length: first frame only)")
    ap.add_argument("--gaps", type=int, nargs="*", default=[],
                    help="also the default matcher with these gap depths (default: only its own, 32)")
    ap.add_argument("--ann", action="store_true",
                    help="also the default matcher through indexes.hnsw (ef 256; built on all cores, needs the ann extra)")
    ap.add_argument("--approx", type=float, nargs="*", default=[],
                    help="also the bounded approximation (certified search pruning at (1+eps) LB > tau) with these eps")
    ap.add_argument("--certified-only", action="store_true",
                    help="only sDTW, the default, the certified search (with counted work) and the --approx variants")
    ap.add_argument("--hidden", type=int, default=0,
                    help="only the hidden-source benchmark (recall, rho, speed) with this many queries per length")
    ap.add_argument("--hidden-methods", nargs="*", default=None,
                    help="only the hidden-source methods whose label contains one of these words")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    sizes = args.sizes or ([60_000] if args.quick else [380_813, 1_038_388])
    n_q = args.queries or (8 if args.quick else 32)
    n_x = args.exact or (3 if args.quick else 6)
    rng = np.random.default_rng(args.seed)
    print("LNG (kNN + graph + path) vs subsequence DTW; F_E^15; kd-tree; one thread; median ms per query")
    if args.hidden_methods:
        for k in [k for k in HIDDEN_METHODS if not any(w in k for w in args.hidden_methods)]:
            del HIDDEN_METHODS[k]
    for n in sizes:
        if args.hidden:
            names: list = []
            space = database_space(n, names=names)
            bench_hidden(space, names, (30, 90), args.hidden, rng)
            continue
        space = database_space(n)
        ann = None
        if args.ann:
            from mocapflow.plugins.similarity.knn.hnsw import HNSWIndex

            t = time.perf_counter()
            ann = SearchSpace(space.clip_id, space.frame, HNSWIndex(ef=256, threads=0).build(space.features), space.features)
            print(f"indexes.hnsw build (all cores) {time.perf_counter() - t:.1f} s")
        bench_size(space, (30, 64, 90), n_q, n_x, args.k, rng, propagate=args.propagate, ann=ann, gaps=args.gaps,
                   approx=args.approx, certified_only=args.certified_only)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
