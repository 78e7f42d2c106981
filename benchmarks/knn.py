"""kNN indexes (Krüger et al. 2010 Table 1): ms per query of ``indexes.kdtree``, ``indexes.sharded``
and ``indexes.hnsw`` against scipy's cKDTree in the same run.

    python benchmarks/knn.py                     # 380,813 and 1,038,388 frames, F_E^15 / F_E^15x3 / F_E^30x3
    python benchmarks/knn.py --sizes 380813 --sets F_E15
    python benchmarks/knn.py --quick             # the bundled examples/data clips

For each database (the augmented corpus of ``benchmarks/corpus.py``) and feature set: single
queries one at a time on one thread (``workers=1``), and a batch on all cores, for k = 16 and
256; printed as ms per query and as the ratio cKDTree / method (> 1: ours faster). The
kd-tree's ``method: auto`` choice is printed (``kdtree`` or ``brute``); the sharded index (2
shards of kd-trees) must return the kd-tree's neighbours exactly; ``indexes.hnsw`` (the ``ann``
extra) prints its recall@k against the exact neighbours at its default ``ef``. Query frames are
random frames of the database, slightly perturbed. Differences under ~20 % are noise on a
shared machine.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from corpus import REPO, augmented_database

from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex
from mocapflow.plugins.similarity.knn.sharded import ShardedIndex

SETS = {"F_E15": {"joints": 5}, "F_E15x3": {"joints": 5, "samples": 3}, "F_E30x3": {"joints": 10, "samples": 3}}


def features(db, name: str) -> np.ndarray:
    from mocapflow.plugins.similarity.knn.end_effectors import EndEffectorFeatures

    return np.ascontiguousarray(EndEffectorFeatures(**SETS[name]).transform(db))


def per_query(fn, qs, single: bool) -> float:
    """ms per query: one call per query (single) or one call for all of them."""
    fn(qs[:2])  # warm-up: numba cache load, page-in
    t = time.perf_counter()
    if single:
        for i in range(len(qs)):
            fn(qs[i : i + 1])
    else:
        fn(qs)
    return 1e3 * (time.perf_counter() - t) / len(qs)


def recall(got: np.ndarray, want: np.ndarray) -> float:
    return float(np.mean([len(set(g.tolist()) & set(w.tolist())) / len(w) for g, w in zip(got, want, strict=True)]))


def bench(x: np.ndarray, groups: np.ndarray, n_queries: int, rng) -> None:
    from scipy.spatial import cKDTree

    qs = x[rng.integers(0, len(x), n_queries)] + rng.normal(0, 0.01 * x.std(0).mean(), (n_queries, x.shape[1]))
    qs = qs.astype(np.float32)
    tree = KDTreeIndex().build(x, groups=groups)
    shards = ShardedIndex(shards=2).build(x, groups=groups)
    ck = cKDTree(x)
    print(f"  {len(x):,} x {x.shape[1]}: kd-tree method {tree.method_} (brute from k={tree.brute_from_k_})")
    hnsw = None
    try:
        from mocapflow.plugins.similarity.knn.hnsw import HNSWIndex

        hnsw = HNSWIndex(threads=0).build(x)
    except Exception as exc:  # the ann extra is optional
        print(f"    (no indexes.hnsw: {exc})")
    print(
        f"    {'k':>4} {'mode':<7} {'cKDTree ms':>10} {'kdtree':>8} {'x':>6} {'sharded':>8} {'x':>6} {'hnsw':>8} "
        f"{'x':>6} {'recall':>7}"
    )
    for k in (16, 256):
        exact = tree.query(qs, k, workers=1)[1]
        assert np.array_equal(shards.query(qs, k)[1], exact), "sharded != kd-tree"
        for single in (True, False):
            w = 1 if single else 0
            t_ck = per_query(lambda q, k=k, w=w: ck.query(q, k, workers=w or -1), qs, single)
            t_kd = per_query(lambda q, k=k, w=w: tree.query(q, k, workers=w), qs, single)
            t_sh = per_query(lambda q, k=k: shards.query(q, k), qs, single)
            row = (
                f"    {k:>4} {'single' if single else 'batch':<7} {t_ck:>10.3f} {t_kd:>8.3f} {t_ck / t_kd:>6.2f} "
                f"{t_sh:>8.3f} {t_ck / t_sh:>6.2f}"
            )
            if hnsw is not None:
                t_hn = per_query(lambda q, k=k, w=w: hnsw.query(q, k, workers=w or -1), qs, single)
                row += f" {t_hn:>8.3f} {t_ck / t_hn:>6.2f} {recall(hnsw.query(qs, k)[1], exact):>7.4f}"
            print(row)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the bundled examples/data clips, F_E^15, 50 queries")
    ap.add_argument("--sizes", type=int, nargs="*", default=[380_813, 1_038_388], help="database sizes in frames")
    ap.add_argument("--sets", nargs="*", default=list(SETS), choices=list(SETS))
    ap.add_argument("--queries", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    if args.quick:
        from mocapflow.framework import MotionDatabase
        from mocapflow.framework.normalize import resample
        from mocapflow.plugins.formats.asf_amc import read_amc

        files = sorted((REPO / "examples" / "data" / "cmu").glob("*/*.amc"))
        db = MotionDatabase([resample(read_amc(f), 30.0) for f in files])
        print("examples/data, F_E15")
        bench(features(db, "F_E15"), db.frame_ids[0], 50, rng)
        return 0
    for n in args.sizes:
        db = augmented_database(n, fps=30)
        for name in args.sets:
            print(f"{n:,} frames, {name}")
            bench(features(db, name), db.frame_ids[0], args.queries, rng)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
