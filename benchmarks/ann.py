"""Approximate kNN libraries on our feature sets: which one backs ``indexes.hnsw`` (issue 13 §3).

    python benchmarks/ann.py --quick        # the real corpus (27,596 frames), 100 queries
    python benchmarks/ann.py                # the 380,813-frame augmented database, 200 queries
    python benchmarks/ann.py --db 1038388

For F_E^15 and the 45-d windowed set F_E^15x3 (``features.end_effectors`` joints 5,
samples 1 / 3; ``--sets F_E30x3`` adds the 90-d set, joints 10, samples 3), each installed library among hnswlib, usearch and faiss (``IndexHNSWFlat``)
builds an HNSW graph (M = 16, ef_construction = 200, one thread, seed 0) and is queried
with single queries on one thread at several ``ef`` (search breadth) for k = 256 (and 16).
Printed per library and ``ef``: recall@k against the exact answer of ``indexes.kdtree``,
ms per query and the ratio to the exact kd-tree measured in the same run, build seconds,
index bytes (as saved), whether save + load returns the same answers, and whether two
builds with the same seed give the same answers (determinism). Query frames are random
rows of the database with a little noise (σ = 1 % of the feature spread), so a query is
not its own nearest row. No assertions: the figures are the output.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

os.environ.setdefault("OMP_NUM_THREADS", "1")


def hnswlib_lib():
    import hnswlib

    class H:
        name = "hnswlib"

        def build(self, x, seed):
            self.ix = hnswlib.Index(space="l2", dim=x.shape[1])
            self.ix.init_index(max_elements=len(x), M=16, ef_construction=200, random_seed=seed)
            self.ix.set_num_threads(1)
            self.ix.add_items(x, np.arange(len(x)), num_threads=1)
            return self

        def query(self, q, k, ef):
            self.ix.set_ef(max(ef, k))
            ids, _ = self.ix.knn_query(q, k=k, num_threads=1)
            return ids

        def save(self, path):
            self.ix.save_index(str(path))

        def load(self, path, x):
            self.ix = hnswlib.Index(space="l2", dim=x.shape[1])
            self.ix.load_index(str(path), max_elements=len(x))
            self.ix.set_num_threads(1)
            return self

    return H()


def usearch_lib():
    from usearch.index import Index

    class U:
        name = "usearch"

        def build(self, x, seed):
            self.ix = Index(ndim=x.shape[1], metric="l2sq", dtype="f32", connectivity=16, expansion_add=200)
            self.ix.add(np.arange(len(x)), x, threads=1)
            return self

        def query(self, q, k, ef):
            self.ix.expansion_search = max(ef, k)
            return np.atleast_2d(np.asarray(self.ix.search(q, k, threads=1).keys))

        def save(self, path):
            self.ix.save(str(path))

        def load(self, path, x):
            self.ix = Index.restore(str(path), view=True)
            return self

    return U()


def faiss_lib():
    import faiss

    class F:
        name = "faiss"

        def build(self, x, seed):
            faiss.omp_set_num_threads(1)
            self.ix = faiss.IndexHNSWFlat(x.shape[1], 16)
            self.ix.hnsw.efConstruction = 200
            self.ix.add(x)
            return self

        def query(self, q, k, ef):
            self.ix.hnsw.efSearch = max(ef, k)
            _, ids = self.ix.search(q, k)
            return ids

        def save(self, path):
            faiss.write_index(self.ix, str(path))

        def load(self, path, x):
            self.ix = faiss.read_index(str(path), faiss.IO_FLAG_MMAP)
            return self

    return F()


def libraries(names=("hnswlib", "usearch", "faiss")):
    out = []
    for make in (hnswlib_lib, usearch_lib, faiss_lib):
        if make.__name__[:-4] not in names:
            continue
        try:
            out.append(make())
        except ImportError as exc:
            print(f"({make.__name__[:-4]} not installed: {exc})")
    return out


def recall(got, want) -> float:
    return float(np.mean([len(set(g[g >= 0].tolist()) & set(w[w >= 0].tolist())) / max((w >= 0).sum(), 1)
                          for g, w in zip(got, want)]))


def one_by_one(fn, qs):
    out, ts = [], []
    for q in qs:
        t = time.perf_counter()
        out.append(fn(q[None])[0])
        ts.append(time.perf_counter() - t)
    return np.asarray(out), float(np.median(ts))


def bench(label, x, n_queries, ks, efs, rng, libs=("hnswlib", "usearch", "faiss"), echo=print):
    from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex

    sd = x.std(axis=0).mean()
    qs = (x[rng.integers(0, len(x), n_queries)] + rng.normal(0, 0.01 * sd, (n_queries, x.shape[1]))).astype(np.float32)
    tree = KDTreeIndex(method="kdtree", workers=1).build(x)
    echo(f"{label}: {len(x):,} x {x.shape[1]}, {n_queries} single queries, one thread")
    exact = {}
    for k in ks:
        tree.query(qs[:2], k)
        exact[k] = one_by_one(lambda q, k=k: tree.query(q, k)[1], qs)
        echo(f"  exact kd-tree k={k}: {exact[k][1] * 1e3:.3f} ms/query")
    echo(f"  {'library':<8} {'k':>4} {'ef':>5} {'recall':>7} {'ms/query':>9} {'kd-tree/this':>12} "
         f"{'build s':>8} {'MB':>7} {'save/load':>9} {'seeded':>6}")
    for lib in libraries(libs):
        t = time.perf_counter()
        lib.build(x, 0)
        t_build = time.perf_counter() - t
        with tempfile.TemporaryDirectory() as tmp:
            p = Path(tmp) / "ix.bin"
            lib.save(p)
            size = p.stat().st_size / 2**20
            before = lib.query(qs[:20], 16, 64)
            twin = type(lib)().build(x, 0)
            seeded = bool(np.array_equal(twin.query(qs[:20], 16, 64), before))
            del twin
            lib.load(p, x)
            loaded = bool(np.array_equal(lib.query(qs[:20], 16, 64), before))
            for k in ks:
                for ef in efs:
                    if ef < k:
                        continue
                    got, tq = one_by_one(lambda q, k=k, ef=ef, lib=lib: lib.query(q, k, ef), qs)
                    echo(f"  {lib.name:<8} {k:>4} {ef:>5} {recall(got, exact[k][0]):>7.4f} {tq * 1e3:>9.3f} "
                         f"{exact[k][1] / tq:>12.2f} {t_build:>8.1f} {size:>7.1f} {str(loaded):>9} {str(seeded):>6}")
        del lib


def main(argv=None) -> int:
    from mocapflow.plugins.similarity.knn.end_effectors import EndEffectorFeatures

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the real corpus only, 100 queries")
    ap.add_argument("--db", type=int, default=None, help="augmented database size (default 380,813)")
    ap.add_argument("--queries", type=int, default=None)
    ap.add_argument("--sets", nargs="*", default=["F_E15", "F_E15x3"], choices=["F_E15", "F_E15x3", "F_E30x3"])
    ap.add_argument("--libs", nargs="*", default=["hnswlib", "usearch", "faiss"])
    ap.add_argument("--ef", type=int, nargs="*", default=[64, 256, 512, 1024], help="search breadths")
    ap.add_argument("-k", type=int, nargs="*", default=[256, 16])
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    from corpus import augmented_database, load_corpus

    db = load_corpus(30.0) if args.quick and args.db is None else augmented_database(args.db or 380_813, fps=30)
    n_q = args.queries or (100 if args.quick else 200)
    rng = np.random.default_rng(args.seed)
    sets = {"F_E15": EndEffectorFeatures(joints=5), "F_E15x3": EndEffectorFeatures(joints=5, samples=3),
            "F_E30x3": EndEffectorFeatures(joints=10, samples=3)}
    for name in args.sets:
        x = np.ascontiguousarray(sets[name].transform(db), np.float32)
        bench(name, x, n_q, args.k, args.ef, rng, args.libs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
