"""Fidelity of the lazy neighborhood graph against exact subsequence DTW (Krüger et al. 2010, §4.2, §5.1).

    python benchmarks/matching_fidelity.py            # HDM05 cuts and CMU, 128 + 128 queries
    python benchmarks/matching_fidelity.py --quick    # HDM05 only, 16 + 16 queries, F_E^15 only

On the real corpus (``../shared/data``, ``MOCAPFLOW_DATA`` overrides; 30 Hz):

1. **LNG vs sDTW** (F_E^15, k = 256, exact kd-tree): for random database segments of 1 s
   and 3 s as queries, the LNG's top-10 matches are compared with exact subsequence DTW:
   the fraction of queries with at least one LNG match ("found"), Spearman's rho between
   each LNG match cost and the sDTW cost of the best path ending at the same frame (mean
   over queries with 3 or more matches, and pooled over all pairs), the fraction of
   matches whose LNG path is the optimal one (equal cost), and the fraction of queries
   whose best match (start, end) is identical. Run twice: with the queries' own clips
   searched too (the own segment is then the trivial best match, as in the paper's setup)
   and hidden from both matchers (only *other* instances count).
2. **Approximate neighbour sets**: ε-approximate kNN (``e0.1``, ``e0.5``) and propagated
   sets (``matchers.lng`` ``propagate``: index searched every 8th query frame, ``p8``, or for
   the first frame only, ``p1st``): fraction of the exact-kNN LNG's top-10 alignments found
   again, identical best matches, and the time ratio (graph included) to the exact LNG.
3. **Query-by-example** on the HDM05 cut classes (Table 2's layout): each cut is a query,
   its own clip hidden from the kNN search; distinct clips are taken in LNG rank order
   (matches spanning at least half the query, ``min_span`` 0.5); reported per class and
   feature set: same-class clips found before the first wrong one (mean over the class's
   queries) and how many of the first 5 clips are of the class (5 = the other cuts); the
   last column is exact subsequence DTW on F_E^15 for reference.
"""
from __future__ import annotations

import argparse
import re
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from corpus import DATA
from matching import random_queries, random_segments

from mocapflow.framework import MotionDatabase
from mocapflow.framework.normalize import resample
from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex
from mocapflow.plugins.similarity.search.graph import build_graph
from mocapflow.framework.matching import SearchSpace, select_matches
from mocapflow.plugins.similarity.search.sdtw import sdtw_costs, subsequence_dtw


def load(corpus: str) -> MotionDatabase:
    from mocapflow.plugins.formats.asf_amc import read_amc

    files = sorted(DATA.glob(f"{corpus}/amc/*/*.amc"))
    if not files:
        raise SystemExit(f"no AMC files under {DATA}/{corpus}/amc")
    return MotionDatabase([resample(read_amc(f), 30.0) for f in files])


def space_for(db: MotionDatabase, feature_set) -> SearchSpace:
    if getattr(feature_set, "requires_fit", False):
        feature_set.fit(db)
    x = feature_set.transform(db)
    clip_id, frame = db.frame_ids
    return SearchSpace(clip_id, frame, KDTreeIndex(method="kdtree", workers=1).build(x, groups=clip_id, frames=frame), x)


class WithoutClip:
    """The index with one clip hidden (leave-one-out query-by-example; kd-tree ``exclude``)."""

    def __init__(self, index, clip: int) -> None:
        self.index, self.clip = index, clip

    def query(self, x, k, radius=None, eps=0.0):
        n = len(x)
        return self.index.query(x, k, radius, eps=eps, exclude=2**40, query_groups=np.full(n, self.clip),
                                query_frames=np.zeros(n, np.int64))


def spearman(a, b) -> float:
    from scipy.stats import spearmanr

    if len(a) < 3 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return float("nan")
    return float(spearmanr(a, b).statistic)


def lng_vs_sdtw(space: SearchSpace, lengths, n_queries: int, k: int, rng, hide_own: bool, echo=print) -> None:
    echo(f"  {'query':>6} {'found':>6} {'rho mean':>9} {'rho pooled':>10} {'optimal paths':>13} {'same best':>9} "
         f"{'appr':>4} {'alignments kept':>15} {'same best':>9} {'kNN time':>9}")
    warm = random_queries(space, 8, 1, rng)[0]  # compile the kernels outside the timings
    for eps in (0.0, 0.1):
        build_graph(warm, space, k=k, eps=eps)
    for m in lengths:
        starts = random_segments(space, m, n_queries, rng)
        qs = [space.features[s : s + m] for s in starts]
        # hiding the query's own clip (from the kNN and from sDTW) asks for *other* instances
        spaces = [SearchSpace(space.clip_id, space.frame, WithoutClip(space.index, int(space.clip_id[s])), space.features)
                  if hide_own else space for s in starts]
        rhos, pool_l, pool_s, optimal, same_best = [], [], [], [], []
        exact_sets, exact_best, t_exact = [], [], 0.0
        for q, s0, sp in zip(qs, starts, spaces):
            t = time.perf_counter()
            g = build_graph(q, sp, k=k)
            t_exact += time.perf_counter() - t
            res = g.matches(count=10)
            cost, st, ln = sdtw_costs(q, space)
            if hide_own:
                cost[space.clip_id == space.clip_id[s0]] = np.inf
            ends = np.arange(len(cost))
            best = select_matches(ends, st, cost, ln, count=1, max_cost=None, rank_by="cost")
            ref_best = (int(st[best[0]]), int(best[0])) if len(best) else None
            exact_sets.append(set(zip(res.start.tolist(), res.end.tolist())))
            exact_best.append((int(res.start[0]), int(res.end[0])) if len(res) else None)
            s_at = cost[res.end]
            rhos.append(spearman(res.cost, s_at))
            pool_l += res.cost.tolist()
            pool_s += s_at.tolist()
            optimal += np.isclose(res.cost, s_at, rtol=1e-5, atol=1e-6).tolist()
            same_best.append(len(res) > 0 and (int(res.start[0]), int(res.end[0])) == ref_best)
        found = np.mean([len(s) > 0 for s in exact_sets])
        line = (f"  {m:>4} f {found:>6.3f} {np.nanmean(rhos):>9.4f} {spearman(np.array(pool_l), np.array(pool_s)):>10.4f} "
                f"{np.mean(optimal):>13.3f} {np.mean(same_best):>9.3f}")
        for label, eps, prop in (("e0.1", 0.1, 0), ("e0.5", 0.5, 0), ("p8", 0.0, 8), ("p1st", 0.0, 1 << 30)):
            kept, best, t_eps = [], [], 0.0
            for q, sp, ex, eb in zip(qs, spaces, exact_sets, exact_best):
                t = time.perf_counter()
                res = build_graph(q, sp, k=k, eps=eps, propagate=prop).matches(count=10)
                t_eps += time.perf_counter() - t
                got = set(zip(res.start.tolist(), res.end.tolist()))
                if ex:  # queries without any exact-kNN alignment have nothing to keep
                    kept.append(len(got & ex) / len(ex))
                best.append(eb == ((int(res.start[0]), int(res.end[0])) if len(res) else None))
            echo(f"{line} {label:>4} {np.mean(kept):>15.3f} {np.mean(best):>9.3f} {t_eps / t_exact:>9.2f}")
            line = " " * len(line)


def clip_class(name: str) -> str:
    m = re.match(r"HDM_[a-z]+_(.+?)_\d+(?:_120)?$", name)
    return m.group(1) if m else name


def query_by_example(db: MotionDatabase, feature_sets: dict, k: int, min_span: float, echo=print) -> None:
    classes = [clip_class(m.name) for m in db.motions]
    table: dict[str, dict[str, str]] = defaultdict(dict)
    columns = [(label, fs, "lng", k) for label, fs in feature_sets.items()]
    columns += [(f"F15 k={kk}", feature_sets["F15"], "lng", kk) for kk in (4 * k, 16 * k)]
    columns += [("F15 sDTW", feature_sets["F15"], "sdtw", 0)]
    for label, fs, how, kk in columns:
        space = space_for(db, fs)
        offsets = db.offsets
        before_wrong, in_top5 = defaultdict(list), defaultdict(list)
        for c, motion in enumerate(db.motions):
            q = space.features[offsets[c] : offsets[c + 1]]
            if how == "lng":
                loo = SearchSpace(space.clip_id, space.frame, WithoutClip(space.index, c), space.features)
                res = build_graph(q, loo, k=kk).matches(count=40, min_span=min_span)
            else:
                res = subsequence_dtw(q, space, count=40, min_span=min_span)
            seen, order = {c}, []
            for s in res.start:
                clip = int(space.clip_id[s])
                if clip not in seen:
                    seen.add(clip)
                    order.append(classes[clip] == classes[c])
            hits = next((i for i, ok in enumerate(order) if not ok), len(order))
            before_wrong[classes[c]].append(hits)
            in_top5[classes[c]].append(sum(order[:5]))
        for cls in before_wrong:
            table[cls][label] = f"{np.mean(before_wrong[cls]):.1f} ({np.mean(in_top5[cls]):.1f})"
        table["(all)"][label] = (f"{np.mean([v for x in before_wrong.values() for v in x]):.1f} "
                                 f"({np.mean([v for x in in_top5.values() for v in x]):.1f})")
    labels = [c[0] for c in columns]
    echo("  same-class clips before the first wrong one, mean over the class's cuts (same-class among the first 5)")
    echo(f"  {'class':<30}" + "".join(f"{lb:>12}" for lb in labels))
    for cls in sorted(table, key=lambda s: (s == "(all)", s)):
        echo(f"  {cls:<30.30}" + "".join(f"{table[cls].get(lb, '-'):>12}" for lb in labels))


def main(argv=None) -> int:
    from mocapflow.plugins.similarity.knn.end_effectors import EndEffectorFeatures

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--queries", type=int, default=None, help="random queries per length (default 128; quick 16)")
    ap.add_argument("-k", type=int, default=256)
    ap.add_argument("--corpora", nargs="*", default=None, help="hdm05 and/or cmu")
    ap.add_argument("--no-qbe", action="store_true", help="skip query-by-example")
    ap.add_argument("--min-span", type=float, default=0.5, help="query-by-example: matches span at least this fraction of the query")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    n_q = args.queries or (16 if args.quick else 128)
    corpora = args.corpora or (["hdm05"] if args.quick else ["hdm05", "cmu"])
    rng = np.random.default_rng(args.seed)
    for corpus in corpora:
        db = load(corpus)
        echo = print
        echo(f"{corpus}: {db.n_clips} clips, {db.n_frames:,} frames at 30 Hz; LNG k={args.k} vs subsequence DTW, F_E^15")
        space = space_for(db, EndEffectorFeatures(joints=5))
        for hide in (False, True):
            echo(f"  queries' own clips {'hidden (other instances only)' if hide else 'searched too'}")
            lng_vs_sdtw(space, (30, 90), n_q, args.k, rng, hide)
        if corpus == "hdm05" and not args.no_qbe:
            sets = {"F15": EndEffectorFeatures(joints=5)}
            if not args.quick:
                from mocapflow.plugins.similarity.knn.pca import PosePCA

                sets.update({"F30": EndEffectorFeatures(joints=10), "F15x3": EndEffectorFeatures(joints=5, samples=3),
                             "Fpca16": PosePCA(n_components=16)})
            echo(f"{corpus}: query-by-example, each cut as query (own clip hidden from the kNN), LNG k={args.k}, "
                 f"min_span {args.min_span}; last column: exact sDTW on F15")
            query_by_example(db, sets, args.k, args.min_span)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
