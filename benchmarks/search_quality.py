"""Search quality of the global matchers on real motion: leave-one-actor-out query-by-example
and recall of exact subsequence DTW's top-10 (issue 13's targets).

    python benchmarks/search_quality.py            # HDM05 cuts, all methods, 64 + 64 recall queries
    python benchmarks/search_quality.py --quick    # fewer methods, 16 + 16 recall queries

On the HDM05 cuts of ``../shared/data`` (``MOCAPFLOW_DATA`` overrides; 30 Hz; F_E^15,
exact kd-tree; ``min_span`` 0.5, the matchers' default):

1. **Query-by-example, leave one actor out**: the database is the cuts of the other two
   actors (its own kd-tree); each cut of the held-out actor is a query; the clips are
   ranked by their best match (``count`` 20 non-overlapping matches); relevant = same
   motion class. Printed per method: mAP (average precision over the ranked clips, a
   relevant clip never returned counts as missed), P@5, queries without any result while
   the database holds their class, and the median ms per query with the ratio to sDTW.
2. **Recall of sDTW's top-10, own clip hidden**: random 1 s and 3 s segments of the cuts as
   queries, the query's clip removed from the database; the share of sDTW's top-10
   alignments whose end row the method's top-10 also holds (``same end``), whose rows it
   overlaps by half (``overlap``), and Spearman's rho of the two costs over the pairs with
   the same end; and the method's time ratio to sDTW.

Methods: ``sdtw`` (exact reference), ``paper`` (LNG, ``gaps 0``, no fill), ``gaps G`` (the
gap-tolerant graph alone, no fill), ``graph`` (the graph's defaults: gaps 32, propagate 2,
fill), ``default`` (``matchers.lng`` as configured by default: certified exact),
``exact`` (certified-exact mode, asked for explicitly), larger ``k`` and propagated sets.
No assertions: the figures are the output.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from corpus import DATA

from mocapflow.framework import MotionDatabase
from mocapflow.framework.normalize import resample
from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex
from mocapflow.plugins.similarity.search.lng import lazy_neighborhood_graph
from mocapflow.framework.matching import SearchSpace
from mocapflow.plugins.similarity.search.sdtw import subsequence_dtw

#: method label -> keyword arguments of lazy_neighborhood_graph (None: subsequence DTW)
METHODS = {
    "sdtw": None,
    "paper k256": dict(gaps=0, fill=False),
    "paper k2048": dict(k=2048, gaps=0, fill=False),
    "gaps4": dict(gaps=4, fill=False),
    "gaps8": dict(gaps=8, fill=False),
    "gaps16": dict(gaps=16, fill=False),
    "gaps32": dict(gaps=32, fill=False),
    "fill gaps16": dict(gaps=16),
    "fill gaps32": dict(gaps=32),
    "fill gaps32 k64": dict(gaps=32, k=64),
    "fill gaps32 k128": dict(gaps=32, k=128),
    "fill gaps48 k64": dict(gaps=48, k=64),
    "fill gaps32 k32": dict(gaps=32, k=32),
    "fill gaps32 p8": dict(gaps=32, propagate=8),
    "fill gaps32 p4": dict(gaps=32, propagate=4),
    "fill gaps32 p2": dict(gaps=32, propagate=2),
    "gaps8 k64": dict(k=64, gaps=8, fill=False),
    "gaps8 p8": dict(gaps=8, propagate=8, fill=False),
    "graph": dict(),  # the gap-tolerant graph's own defaults (the matcher default until 2026-12-02)
    "default": None,
    "exact": dict(exact=True),
    # the certified search forced to prune (no whole DP on these small databases), and its bounded approximation
    "pruned": dict(exact=True, direct_cells=0),
    **{f"approx{e:g}": dict(exact=True, approx=e, direct_cells=0) for e in (0.1, 0.15, 0.25, 0.5, 1.0, 2.0, np.inf)},
    # the seed windows alone (approx inf) with denser seeds: query frames x neighbours per frame (x count)
    **{f"seeds{f}x{k}": dict(exact=True, approx=np.inf, direct_cells=0, seed_frames=f, seed_k=k)
       for f, k in ((5, 20), (10, 6), (10, 20), (20, 20), (30, 50))},
}
# every entry above but sdtw/default/exact is a configuration of the graph (exact: false)
METHODS = {k: (dict(v, exact=False) if not (k in ("sdtw", "default") or (v or {}).get("exact")) else v) for k, v in METHODS.items()}
METHODS["default"] = dict()  # matchers.lng as configured by default (certified exact since 2026-12-02)
QUICK = ("sdtw", "paper k256", "gaps8", "default", "exact")


def load_hdm05() -> tuple[MotionDatabase, list[str], list[str]]:
    """The HDM05 cuts at 30 Hz, each clip's actor and motion class."""
    from mocapflow.plugins.formats.asf_amc import read_amc

    files = sorted(DATA.glob("hdm05/amc/*/*.amc"))
    if not files:
        raise SystemExit(f"no HDM05 AMC files under {DATA}/hdm05/amc")
    db = MotionDatabase([resample(read_amc(f), 30.0) for f in files])
    actors = [f.parent.name for f in files]
    classes = [f.stem.split("_")[2] for f in files]  # HDM_<actor>_<class>_<nnn>_120
    return db, actors, classes


def subspace(x, clip_id, frame, keep: np.ndarray) -> SearchSpace:
    """The rows ``keep`` as their own database, with their own exact kd-tree."""
    idx = KDTreeIndex(method="kdtree", workers=1).build(x[keep], groups=clip_id[keep], frames=frame[keep])
    return SearchSpace(clip_id[keep], frame[keep], idx, x[keep])


def run(method, q, space, count):
    kw = METHODS[method]
    t = time.perf_counter()
    res = subsequence_dtw(q, space, count=count) if kw is None else lazy_neighborhood_graph(q, space, count=count, **kw)
    return res, time.perf_counter() - t


def average_precision(ranked: list[bool], n_relevant: int) -> float:
    hits, total = 0, 0.0
    for r, ok in enumerate(ranked, 1):
        if ok:
            hits += 1
            total += hits / r
    return total / n_relevant if n_relevant else float("nan")


def qbe_leave_one_actor_out(db, x, actors, classes, methods, count, echo=print) -> None:
    clip_id, frame = db.frame_ids
    acts = np.asarray(actors)
    echo(f"  query-by-example, leave one actor out ({', '.join(sorted(set(actors)))}); count {count}, min_span 0.5")
    stats = {m: {"ap": [], "p5": [], "empty": 0, "t": []} for m in methods}
    for actor in sorted(set(actors)):
        space = subspace(x, clip_id, frame, acts[clip_id] != actor)
        db_classes = {classes[c] for c in np.unique(space.clip_id)}
        for c in np.flatnonzero(acts == actor):
            q = x[db.offsets[c] : db.offsets[c + 1]]
            n_rel = sum(classes[o] == classes[c] for o in np.unique(space.clip_id))
            for m in methods:
                res, t = run(m, q, space, count)
                order: list[int] = []
                for s in res.start:
                    clip = int(space.clip_id[s])
                    if clip not in order:
                        order.append(clip)
                ranked = [classes[o] == classes[c] for o in order]
                st = stats[m]
                st["ap"].append(average_precision(ranked, n_rel))
                st["p5"].append(sum(ranked[:5]) / 5)
                st["empty"] += int(len(res) == 0 and classes[c] in db_classes)
                st["t"].append(t)
    t_ref = np.median(stats["sdtw"]["t"]) if "sdtw" in stats else float("nan")
    echo(f"    {'method':<14} {'mAP':>6} {'P@5':>6} {'empty':>6} {'ms/query':>9} {'sDTW/this':>9}")
    for m in methods:
        st = stats[m]
        t = np.median(st["t"])
        echo(f"    {m:<14} {np.nanmean(st['ap']):>6.3f} {np.mean(st['p5']):>6.3f} {st['empty']:>6d} "
             f"{t * 1e3:>9.2f} {t_ref / t:>9.2f}")


def recall_own_clip_hidden(db, x, lengths, n_queries, methods, rng, echo=print) -> None:
    from scipy.stats import spearmanr

    clip_id, frame = db.frame_ids
    echo(f"  recall of sDTW's top-10, query's own clip hidden; {n_queries} random queries per length")
    echo(f"    {'query':>6} {'method':<14} {'same end':>9} {'overlap':>8} {'rho':>7} {'found 10':>9} {'sDTW/this':>9}")
    spaces: dict[int, SearchSpace] = {}
    for m_len in lengths:
        starts = []
        while len(starts) < n_queries:
            c = int(rng.integers(db.n_clips))
            a, b = db.offsets[c], db.offsets[c + 1]
            if b - a >= m_len:
                starts.append((c, int(rng.integers(a, b - m_len + 1))))
        rows = {m: {"end": [], "ov": [], "ca": [], "cb": [], "full": [], "t": []} for m in methods if m != "sdtw"}
        t_ref = []
        for c, s in starts:
            if c not in spaces:
                spaces[c] = subspace(x, clip_id, frame, clip_id != c)
            space = spaces[c]
            q = x[s : s + m_len]
            ref, t = run("sdtw", q, space, 10)
            t_ref.append(t)
            for m in rows:
                res, t = run(m, q, space, 10)
                r = rows[m]
                r["t"].append(t)
                r["full"].append(len(res) == 10)
                ends = {int(e): float(cc) for e, cc in zip(res.end, res.cost)}
                for rs, re_, rc in zip(ref.start, ref.end, ref.cost):
                    hit = int(re_) in ends
                    r["end"].append(hit)
                    if hit:
                        r["ca"].append(float(rc))
                        r["cb"].append(ends[int(re_)])
                    ov = np.minimum(res.end, re_) - np.maximum(res.start, rs)
                    r["ov"].append(bool(np.any(ov >= 0.5 * (re_ - rs))))
        for m, r in rows.items():
            rho = spearmanr(r["ca"], r["cb"]).statistic if len(r["ca"]) > 2 else float("nan")
            echo(f"    {m_len:>4} f {m:<14} {np.mean(r['end']):>9.3f} {np.mean(r['ov']):>8.3f} {rho:>7.4f} "
                 f"{np.mean(r['full']):>9.3f} {np.median(t_ref) / np.median(r['t']):>9.2f}")


def _recall(x, clip_id, frame, starts, m_len, kw, cache) -> tuple[float, float, list, list]:
    """Share of sDTW's top-10 ends found by ``lazy_neighborhood_graph(**kw)``, and Spearman's rho of
    the costs over them, for the queries ``starts`` ((clip, first row) pairs; own clip hidden)."""
    from scipy.stats import spearmanr

    hit, ca, cb = [], [], []
    for c, s in starts:
        if c not in cache:
            cache[c] = subspace(x, clip_id, frame, clip_id != c)
        space = cache[c]
        q = x[s : s + m_len]
        ref = subsequence_dtw(q, space, count=10)
        res = lazy_neighborhood_graph(q, space, count=10, **kw)
        ends = {int(e): float(cc) for e, cc in zip(res.end, res.cost)}
        for re_, rc in zip(ref.end, ref.cost):
            hit.append(int(re_) in ends)
            if hit[-1]:
                ca.append(float(rc))
                cb.append(ends[int(re_)])
    rho = spearmanr(ca, cb).statistic if len(ca) > 2 and len(set(ca)) > 1 else 1.0
    return float(np.mean(hit)), float(rho), ca, cb


def choose_approx_loao(db, x, actors, grid, n_queries, rng, echo=print) -> None:
    """``approx`` chosen leave one actor out: per held-out actor, the largest value of ``grid``
    whose recall of sDTW's top-10 is >= 0.95 and rho >= 0.99 for 1 s and 3 s queries from the
    *other* actors' clips (own clip hidden), then measured on the held-out actor's queries."""
    clip_id, frame = db.frame_ids
    acts = np.asarray(actors)
    echo(f"  approx chosen leave one actor out (grid {', '.join(f'{e:g}' for e in grid)}; recall >= 0.95, rho >= 0.99 "
         f"on the other actors' queries; {n_queries} queries per length and set; pruned search forced)")
    echo(f"    {'held out':<9} {'chosen':>7} {'tune recall 1s/3s':>18} {'held-out recall 1s/3s':>22} {'rho 1s/3s':>16}")
    cache: dict = {}

    def draw(clips, m_len):
        out = []
        while len(out) < n_queries:
            c = int(rng.choice(clips))
            a, b = db.offsets[c], db.offsets[c + 1]
            if b - a >= m_len:
                out.append((c, int(rng.integers(a, b - m_len + 1))))
        return out

    for actor in sorted(set(actors)):
        mine, others = np.flatnonzero(acts == actor), np.flatnonzero(acts != actor)
        tune = {m: draw(others, m) for m in (30, 90)}
        test = {m: draw(mine, m) for m in (30, 90)}
        chosen, tune_rec = 0.0, (1.0, 1.0)
        for e in sorted(grid):
            kw = dict(exact=True, approx=e, direct_cells=0)
            r = [_recall(x, clip_id, frame, tune[m], m, kw, cache)[:2] for m in (30, 90)]
            if all(rec >= 0.95 and rho >= 0.99 for rec, rho in r):
                chosen, tune_rec = e, (r[0][0], r[1][0])
        kw = dict(exact=True, approx=chosen, direct_cells=0)
        r = [_recall(x, clip_id, frame, test[m], m, kw, cache)[:2] for m in (30, 90)]
        echo(f"    {actor:<9} {chosen:>7g} {tune_rec[0]:>8.3f} / {tune_rec[1]:.3f} {r[0][0]:>12.3f} / {r[1][0]:.3f} "
             f"{r[0][1]:>7.4f} / {r[1][1]:.4f}")


def main(argv=None) -> int:
    from mocapflow.plugins.similarity.knn.end_effectors import EndEffectorFeatures

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help=f"methods {', '.join(QUICK)}; 16 recall queries per length")
    ap.add_argument("--methods", nargs="*", default=None, choices=list(METHODS))
    ap.add_argument("--queries", type=int, default=None, help="recall queries per length (default 64; quick 16)")
    ap.add_argument("--count", type=int, default=20, help="matches per query-by-example query")
    ap.add_argument("--no-qbe", action="store_true")
    ap.add_argument("--no-recall", action="store_true")
    ap.add_argument("--choose-approx", type=float, nargs="*", default=None,
                    help="choose the bounded approximation's approx from this grid leave one actor out (then exit)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    methods = args.methods or list(QUICK if args.quick else METHODS)
    if "sdtw" not in methods:
        methods = ["sdtw", *methods]
    n_q = args.queries or (16 if args.quick else 64)
    db, actors, classes = load_hdm05()
    x = EndEffectorFeatures(joints=5).transform(db)
    print(f"hdm05 cuts: {db.n_clips} clips, {db.n_frames:,} frames at 30 Hz, {len(set(classes))} classes; F_E^15, "
          f"kd-tree, one thread")
    if args.choose_approx is not None:
        choose_approx_loao(db, x, actors, args.choose_approx or [0.05, 0.1, 0.25, 0.5], n_q,
                           np.random.default_rng(args.seed))
        return 0
    # compile the kernels outside the timings
    warm = subspace(x, *db.frame_ids, np.arange(db.n_frames) < db.offsets[3])
    for m in methods:
        run(m, x[:12], warm, 3)
    if not args.no_qbe:
        qbe_leave_one_actor_out(db, x, actors, classes, methods, args.count)
    if not args.no_recall:
        recall_own_clip_hidden(db, x, (30, 90), n_q, methods, np.random.default_rng(args.seed))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
