"""The sharded-index section of ``benchmarks/scale.py``: ``indexes.sharded`` (2 shards of
F_E^15 kd-trees) against one kd-tree on the grown corpus (``benchmarks/corpus.py``): identical
kNN, build and batch-query throughput with 2 worker processes against 1, bytes per row."""

from __future__ import annotations

import os
import resource
import time
from pathlib import Path

import numpy as np


def _load() -> str:
    return Path("/proc/loadavg").read_text().split(" ", 3)[:3].__str__().replace("'", "")


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _proc_cpu(pids) -> list[float]:
    """CPU seconds (user + system) of processes, from /proc."""
    tick, out = os.sysconf("SC_CLK_TCK"), []
    for pid in pids:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        out.append((int(fields[11]) + int(fields[12])) / tick)
    return out


def _best_batch(fn, ex, repeats: int = 3) -> tuple[float, dict]:
    """Best wall time of ``fn()`` over repeats, and the CPU seconds the client and each pool
    worker spent in that best repeat (what the batch costs on idle cores)."""
    best, busy = np.inf, {}
    for _ in range(repeats):
        pids = list(getattr(getattr(ex, "_pool", None), "_processes", None) or {})
        w0, c0 = _proc_cpu(pids), time.process_time()
        t0 = time.perf_counter()
        fn()
        t = time.perf_counter() - t0
        if t < best:
            best = t
            busy = {
                "client": time.process_time() - c0,
                "workers": [b - a for a, b in zip(w0, _proc_cpu(pids), strict=True)],
            }
    return best, busy


def index_figures(n_frames: int, n_queries: int, k: int, tmp: Path) -> dict:
    from corpus import augmented_database

    from mocapflow.framework.executors import LocalExecutor
    from mocapflow.plugins.similarity.knn.end_effectors import EndEffectorFeatures
    from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex
    from mocapflow.plugins.similarity.knn.sharded import ShardedIndex

    t0 = time.perf_counter()
    db = augmented_database(n_frames, fps=30)
    x = EndEffectorFeatures(joints=5).transform(db)
    groups, frames = db.frame_ids
    print(f"\nsharded index: {len(x):,} frames of F_E^15 ({x.shape[1]} dims) ready in {time.perf_counter() - t0:.1f} s")
    params = {"method": "kdtree", "workers": 1}  # one thread per process: the workers are the parallelism
    t0 = time.perf_counter()
    one = KDTreeIndex(params).build(x, groups=groups, frames=frames)
    t_one = time.perf_counter() - t0
    t0 = time.perf_counter()
    sh = ShardedIndex(shards=2, index_params=params).build(x, groups=groups, frames=frames)
    t_sh = time.perf_counter() - t0
    sh.save(tmp / "sharded")
    one.save(tmp / "one")
    bytes_row = sum(p.stat().st_size for p in (tmp / "one").glob("*.npy")) / len(x)
    rng = np.random.default_rng(0)
    q = (x[rng.choice(len(x), n_queries, replace=False)] + rng.normal(0, 0.01, (n_queries, x.shape[1]))).astype(
        np.float32
    )
    a = one.query(q, k)
    b = sh.query(q, k)
    same = bool(np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]))
    ar, br = one.query(q, k, 0.15), sh.query(q, k, 0.15)
    same_r = bool(np.array_equal(ar[0], br[0]) and np.array_equal(ar[1], br[1]))
    loaded = ShardedIndex.load(tmp / "sharded")
    out = {
        "frames": len(x),
        "identical_knn": same,
        "identical_radius": same_r,
        "bytes_per_row": bytes_row,
        "build_one_s": t_one,
        "build_two_shards_serial_s": t_sh,
    }
    # numba threads instead of processes: one kd-tree with 2 threads (before this process is
    # limited to one thread below)
    out["batch_s_one_index_2threads"], out["busy_one_index_2threads"] = _best_batch(
        lambda: one.query(q, k, workers=2), None
    )
    from mocapflow.framework.threads import limit_threads

    limit_threads(1)
    # one process: the whole batch in this process, one numba thread (the baseline of the target)
    out["batch_s_1w"], out["busy_1w"] = _best_batch(lambda: loaded.query(q, k), None)
    for fan_out in ("queries", "shards"):
        loaded.params = loaded.params.model_copy(update={"fan_out": fan_out})
        ex = LocalExecutor(2, min_items_for_pool=1, threads=1)
        try:
            loaded.query(q[:8], k, executor=ex)  # warm-up: each worker loads the shards once
            best, busy = _best_batch(lambda ex=ex: loaded.query(q, k, executor=ex), ex)
            got = loaded.query(q, k, executor=ex)
            assert np.array_equal(got[1], a[1]) and np.array_equal(got[0], a[0])
        finally:
            ex.close()
        out[f"batch_s_2w_{fan_out}"], out[f"busy_2w_{fan_out}"] = best, busy
    loaded.params = loaded.params.model_copy(update={"fan_out": "queries"})
    out["batch_s_2w"] = out["batch_s_2w_queries"]
    out["batch_s_one_index"], out["busy_one_index"] = _best_batch(lambda: one.query(q, k, workers=1), None)
    shard_t, shard_cpu = {}, {}
    for s, shard in enumerate(sh.shards_):  # per-shard figures the projections use
        t0, c0 = time.perf_counter(), time.process_time()
        shard.query(q, k)
        shard_t[s], shard_cpu[s] = time.perf_counter() - t0, time.process_time() - c0
    out["shard_query_cpu_s"] = list(shard_cpu.values())
    out["shard_rows"] = [int(b - a) for a, b in zip(sh.offsets_[:-1], sh.offsets_[1:], strict=True)]
    out["shard_query_s"] = list(shard_t.values())
    out["peak_rss_mb"] = _rss_mb()
    print(f"  identical to one kd-tree: kNN {same}, radius 0.15 {same_r} ({n_queries} queries, k={k})")
    print(
        f"  build: one index {t_one:.2f} s, 2 shards one after the other {t_sh:.2f} s; {bytes_row:.1f} bytes/row on disk"
    )
    bq, bs = out["busy_2w_queries"], out["busy_2w_shards"]
    print(f"  batch of {n_queries} queries, k={k} (load average {_load()}):")
    print("    (wall s, then CPU s of each process: on idle cores a batch takes about client + busiest worker)")
    print(
        f"    one kd-tree, 1 thread {out['batch_s_one_index']:.3f} s (CPU {out['busy_one_index']['client']:.3f} s); "
        f"2 numba threads {out['batch_s_one_index_2threads']:.3f} s (CPU {out['busy_one_index_2threads']['client']:.3f} s "
        f"over both threads) -> {out['batch_s_one_index'] / out['batch_s_one_index_2threads']:.2f}x wall"
    )
    base_cpu = out["busy_1w"]["client"]
    print(f"    sharded, 1 process {out['batch_s_1w']:.3f} s (CPU {base_cpu:.3f} s)")
    for fan_out, busy in (("queries", bq), ("shards", bs)):
        t = out[f"batch_s_2w_{fan_out}"]
        print(
            f"    sharded, 2 processes, fan_out {fan_out}: {t:.3f} s -> {out['batch_s_1w'] / t:.2f}x throughput; "
            f"CPU busy: client {busy['client']:.3f} s, workers {', '.join(f'{w:.3f}' for w in busy['workers'])} s "
            f"-> {base_cpu / (busy['client'] + max(busy['workers'], default=0)):.2f}x on 2 idle cores"
        )
    print(
        f"  per shard ({out['shard_rows']} rows): {[round(t, 3) for t in out['shard_query_s']]} s per batch "
        f"(CPU {[round(t, 3) for t in out['shard_query_cpu_s']]} s); peak RSS {out['peak_rss_mb']:.0f} MB"
    )
    return out
