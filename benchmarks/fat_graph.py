"""Fat-graph base poses (Krüger et al. 2010 §5.3): kd-tree O(n log n) versus all pairs O(n^2).

    python benchmarks/fat_graph.py            # kd-tree at 100 k, 380 k, 1 M frames; quadratic to 40 k
    python benchmarks/fat_graph.py --quick    # synthetic motion: kd-tree at 2 k, 4 k, 8 k; quadratic to 4 k

Databases are prefixes of the augmented corpus (``benchmarks/corpus.py``), features F_E^15
(``features.end_effectors``, ``joints: 5``), radius and k the step's defaults. Times cover
the neighbourhood search (index build + capped radius queries, or the dense distance
matrix in blocks) plus the shared greedy cover; feature computation is excluded. Where both
run, the base poses are checked to be identical. The exponent b of ``time ~ n^b`` is fitted
by least squares in log-log space.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from corpus import augmented_database

from mocapflow.framework import load_registries
from mocapflow.plugins.similarity.applications._fat_graph_kernels import greedy_cover
from mocapflow.plugins.similarity.applications.fat_graph import FatGraphParams, radius_neighbours


def quadratic_neighbours(x: np.ndarray, radius: float, k: int, block: int = 2048) -> np.ndarray:
    """All-pairs construction (dense distances in row blocks, partial selection of the k
    nearest, ties to the smaller id as the index does)."""
    n = len(x)
    x = x.astype(np.float64)
    sq = (x * x).sum(1)
    ids = np.full((n, k), -1, np.int32)
    kk = min(k, n)
    for s in range(0, n, block):
        d2 = np.maximum(sq[s : s + block, None] + sq[None, :] - 2.0 * x[s : s + block] @ x.T, 0.0)
        part = np.argpartition(d2, kk - 1, axis=1)[:, :kk]
        pd = np.take_along_axis(d2, part, 1)
        order = np.lexsort((part, pd), axis=1)
        part, pd = np.take_along_axis(part, order, 1), np.take_along_axis(pd, order, 1)
        ids[s : s + block, :kk] = np.where(pd <= radius * radius, part, -1)
    return ids


def fit_exponent(n: list[int], t: list[float]) -> float:
    return float(np.polyfit(np.log(n), np.log(t), 1)[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--save-features", metavar="NPY", help="store the F_E^15 matrix (float32) and stop")
    ap.add_argument(
        "--features",
        metavar="NPY",
        help="use a stored F_E^15 matrix instead of the corpus (e.g. on a machine without ../shared/data)",
    )
    ap.add_argument(
        "--sample",
        type=int,
        default=0,
        metavar="N",
        help="estimate the search at the kd-tree sizes from N random queries (build timed in full); "
        "the greedy cover is then not run",
    )
    ap.add_argument("--sizes", type=int, nargs="*", help="kd-tree database sizes (default per --quick)")
    ap.add_argument("--quadratic-sizes", type=int, nargs="*", help="all-pairs sizes (default per --quick)")
    args = ap.parse_args()
    p = FatGraphParams()
    reg = load_registries(entry_points=False)
    fe15 = reg["features"].get("end_effectors")({"joints": 5})
    Tree = reg["indexes"].get("kdtree")
    sizes = args.sizes or ([2_000, 4_000, 8_000] if args.quick else [100_000, 380_813, 1_038_388])
    quad_sizes = args.quadratic_sizes or ([1_000, 2_000, 4_000] if args.quick else [5_000, 10_000, 20_000, 40_000])

    t0 = time.perf_counter()
    if args.quick:
        from mocapflow.framework import MotionDatabase
        from mocapflow.framework.synthetic import synthetic_motion

        x_all = fe15.transform(MotionDatabase([synthetic_motion(400, seed=s) for s in range(20)]))
    elif args.features:
        x_all = np.load(args.features)
        print(f"F_E^15 of {len(x_all)} frames loaded from {args.features}; radius {p.radius}, k {p.k}")
    else:
        db = augmented_database(max(sizes), fps=30)
        x_all = fe15.transform(db)
        print(
            f"augmented corpus: {db.n_frames} frames, F_E^15 computed in {time.perf_counter() - t0:.0f} s; "
            f"radius {p.radius}, k {p.k}"
        )
    if args.save_features:
        np.save(args.save_features, np.ascontiguousarray(x_all, np.float32))
        return
    if len(x_all) < max(sizes):
        raise SystemExit(f"need {max(sizes)} frames, have {len(x_all)}")

    greedy_cover(np.full((2, 2), -1), 0)  # numba compile, not timed
    Tree().build(x_all[:1000]).query(x_all[:10], p.k, radius=p.radius)
    # prefixes of the augmented database are the smaller databases (clip order is fixed)
    if args.sample:
        est_n, est_t = [], []
        rng = np.random.default_rng(0)
        print(f"\n{'n':>9} {'build s':>8} {'query/s':>9} {'est. search s':>14}   ({args.sample} sampled queries)")
        for n in sizes:
            x = np.ascontiguousarray(x_all[:n])
            t = time.perf_counter()
            tree = Tree().build(x)
            tb = time.perf_counter() - t
            q = x[rng.choice(n, min(args.sample, n), replace=False)]
            t = time.perf_counter()
            radius_neighbours(tree, q, p.radius, p.k)
            tq = time.perf_counter() - t
            est = tb + tq * n / len(q)
            print(f"{n:>9} {tb:8.2f} {len(q) / tq:9.0f} {est:14.1f}")
            est_n.append(n)
            est_t.append(est)
        print(
            f"fitted exponent of the estimated search time ({sizes[0]}..{sizes[-1]}): {fit_exponent(est_n, est_t):.2f}"
        )
        return
    kd_n, kd_t, kd_ids = [], [], {}
    print(f"\n{'n':>9} {'method':>10} {'search s':>9} {'greedy s':>9} {'total s':>9} {'bases':>7}")
    for n in sorted(set(sizes) | set(quad_sizes)):
        x = np.ascontiguousarray(x_all[:n])
        t = time.perf_counter()
        ids = radius_neighbours(Tree().build(x), x, p.radius, p.k)
        ts = time.perf_counter() - t
        t = time.perf_counter()
        bases, _, _ = greedy_cover(ids, 0)
        tg = time.perf_counter() - t
        print(f"{n:>9} {'kd-tree':>10} {ts:9.2f} {tg:9.2f} {ts + tg:9.2f} {len(bases):>7}")
        kd_n.append(n)
        kd_t.append(ts + tg)
        if n in quad_sizes:
            kd_ids[n] = (bases, ts + tg)
    quad_t = []
    for n in quad_sizes:
        x = np.ascontiguousarray(x_all[:n])
        t = time.perf_counter()
        ids = quadratic_neighbours(x, p.radius, p.k)
        ts = time.perf_counter() - t
        t = time.perf_counter()
        bases, _, _ = greedy_cover(ids, 0)
        tg = time.perf_counter() - t
        quad_t.append(ts + tg)
        same = np.array_equal(bases, kd_ids[n][0])
        print(
            f"{n:>9} {'all-pairs':>10} {ts:9.2f} {tg:9.2f} {ts + tg:9.2f} {len(bases):>7}   "
            f"same base poses as kd-tree: {same}; kd-tree {quad_t[-1] / kd_ids[n][1]:.1f}x faster"
        )
    big = [i for i, n in enumerate(kd_n) if n >= min(sizes)]
    print(
        f"\nfitted exponent, kd-tree ({kd_n[big[0]]}..{kd_n[-1]} frames): {fit_exponent([kd_n[i] for i in big], [kd_t[i] for i in big]):.2f}"
    )
    print(f"fitted exponent, kd-tree ({quad_sizes[0]}..{kd_n[-1]} frames): {fit_exponent(kd_n, kd_t):.2f}")
    print(
        f"fitted exponent, all pairs ({quad_sizes[0]}..{quad_sizes[-1]} frames): {fit_exponent(quad_sizes, quad_t):.2f}"
    )
    b = fit_exponent(quad_sizes, quad_t)
    est = quad_t[-1] * (kd_n[-1] / quad_sizes[-1]) ** b
    print(f"all pairs extrapolated to {kd_n[-1]} frames: ~{est / 3600:.1f} h (kd-tree: {kd_t[-1]:.0f} s)")


if __name__ == "__main__":
    main()
