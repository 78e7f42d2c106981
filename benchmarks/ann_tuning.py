"""Can an approximate 256-NN search reach 10x the exact kd-tree at recall >= 0.99? (issue 13 §3)

    python benchmarks/ann_tuning.py                 # 380,813 frames, F_E^15, 200 single queries
    python benchmarks/ann_tuning.py --db 1038388 --libs hnswlib
    python benchmarks/ann_tuning.py --quick         # the real corpus (27,596 frames), 50 queries

Beyond ``benchmarks/ann.py`` (M = 16 graphs): graph degree and vector types, an inverted
file, and the exact kd-tree's own epsilon search, each against ``indexes.kdtree``'s exact
answer in the same run (query rows: database rows plus 1 % noise, as in ``ann.py``; single
queries on one thread; builds on one thread, seed 0):

* hnswlib, M = 8, 12, 16 (ef_construction 200), ef = 256, 320, 400 (hnswlib needs ef >= k);
* usearch, connectivity 16 in f32, f16 and i8, and 8 in f32 (expansion_add 200);
* faiss ``IndexIVFFlat`` (exact distances of the probed lists), nlist 1024 and 4096 (trained on
  64 points per list), nprobe 4-32;
* ``indexes.kdtree`` with ``eps`` 0.1-2 (the k-th distance within (1 + eps) of the true one);
* best-bin-first search of the same tree with a scan budget (``_bbf_kernels.py``, FLANN's
  ``checks``): buckets of 64 (the index's) and 16 points, 512-8,192 points scanned.

Printed: recall@256, ms per query, kd-tree / this, build seconds. No assertions.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
os.environ.setdefault("OMP_NUM_THREADS", "1")


def single(fn, qs):
    out, ts = [], []
    for q in qs:
        t = time.perf_counter()
        out.append(np.asarray(fn(q[None])).reshape(-1))
        ts.append(time.perf_counter() - t)
    return out, float(np.median(ts))


def candidates(x, libs):
    """(label, build() -> query(q, k, setting), settings) per configuration."""
    d = x.shape[1]
    if "hnswlib" in libs:
        import hnswlib

        for m in (8, 12, 16):
            def build(m=m):
                ix = hnswlib.Index(space="l2", dim=d)
                ix.init_index(max_elements=len(x), M=m, ef_construction=200, random_seed=0)
                ix.set_num_threads(1)
                ix.add_items(x, np.arange(len(x)), num_threads=1)

                def query(q, k, ef):
                    ix.set_ef(ef)
                    return ix.knn_query(q, k=k, num_threads=1)[0]
                return query
            yield f"hnswlib M {m}", build, ("ef", (256, 320, 400))
    if "usearch" in libs:
        from usearch.index import Index

        for m, dtype in ((16, "f32"), (16, "f16"), (16, "i8"), (8, "f32")):
            def build(m=m, dtype=dtype):
                ix = Index(ndim=d, metric="l2sq", dtype=dtype, connectivity=m, expansion_add=200)
                ix.add(np.arange(len(x)), x, threads=1)

                def query(q, k, ef):
                    ix.expansion_search = ef
                    return np.asarray(ix.search(q, k, threads=1).keys)
                return query
            yield f"usearch {dtype} M {m}", build, ("ef", (256, 320, 400))
    if "faiss" in libs:
        import faiss

        faiss.omp_set_num_threads(1)
        for nlist in (1024, 4096):
            def build(nlist=nlist):
                ix = faiss.IndexIVFFlat(faiss.IndexFlatL2(d), d, nlist)
                ix.cp.seed = 0
                ix.train(x[np.random.default_rng(0).choice(len(x), min(len(x), 64 * nlist), replace=False)])
                ix.add(x)

                def query(q, k, nprobe):
                    ix.nprobe = nprobe
                    return ix.search(q, k)[1]
                return query
            yield f"faiss IVFFlat {nlist}", build, ("nprobe", (4, 8, 16, 32))
    if "kdtree" in libs:
        from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex

        def build():
            tree = KDTreeIndex(method="kdtree", workers=1).build(x)
            return lambda q, k, eps: tree.query(q, k, eps=eps)[1]
        yield "kdtree eps", build, ("eps", (0.1, 0.25, 0.5, 1.0, 2.0))
        from _bbf_kernels import bbf_query

        for leaf in (64, 16):
            def build(leaf=leaf):
                tree = KDTreeIndex(method="kdtree", workers=1, leafsize=leaf).build(x)
                arrays = tree._tree_args()[0]
                data, perm, start, end, left, right, _, _, blo, bhi = arrays[:10]

                def query(q, k, checks):
                    return bbf_query(np.asarray(q, np.float64)[0], k, checks, data, perm, start, end,
                                     left, right, blo, bhi)
                return query
            yield f"kdtree bbf leaf {leaf}", build, ("checks", (512, 1024, 2048, 4096, 8192))


def main(argv=None) -> int:
    from corpus import augmented_database, load_corpus

    from mocapflow.plugins.similarity.knn.end_effectors import EndEffectorFeatures
    from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the real corpus only, 50 queries")
    ap.add_argument("--db", type=int, default=380_813)
    ap.add_argument("--queries", type=int, default=None, help="default 200 (quick 50)")
    ap.add_argument("-k", type=int, default=256)
    ap.add_argument("--libs", nargs="*", default=["hnswlib", "usearch", "faiss", "kdtree"])
    args = ap.parse_args(argv)
    db = load_corpus(30.0) if args.quick else augmented_database(args.db, fps=30)
    x = np.ascontiguousarray(EndEffectorFeatures(joints=5).transform(db))
    n_q = args.queries or (50 if args.quick else 200)
    rng = np.random.default_rng(0)
    sd = x.std(axis=0).mean()
    qs = (x[rng.integers(0, len(x), n_q)] + rng.normal(0, 0.01 * sd, (n_q, x.shape[1]))).astype(np.float32)
    k = args.k
    tree = KDTreeIndex(method="kdtree", workers=1).build(x)
    tree.query(qs[:2], k)
    exact, t_exact = single(lambda q: tree.query(q, k)[1], qs)
    print(f"F_E^15, {len(x):,} rows, k = {k}, {len(qs)} single queries; exact kd-tree {t_exact * 1e3:.3f} ms/query; "
          f"load average {open('/proc/loadavg').read().split()[0]}")
    for label, build, (pname, values) in candidates(x, args.libs):
        t = time.perf_counter()
        query = build()
        t_build = time.perf_counter() - t
        query(qs[:2], k, values[0])
        for v in values:
            got, tq = single(lambda q, v=v: query(q, k, v), qs)
            rec = np.mean([len(set(g.tolist()) & set(w.tolist())) / k for g, w in zip(got, exact)])
            print(f"  {label:<22} {pname} {v:<5g} recall {rec:.4f}  {tq * 1e3:7.3f} ms  x{t_exact / tq:5.2f}  "
                  f"build {t_build:6.1f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
