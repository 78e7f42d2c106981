"""Global search: speed of ``matchers.search`` and the graph against subsequence DTW, and retrieval quality.

    python benchmarks/search.py                  # 380,813 and 1,038,388 frames; HDM05 quality
    python benchmarks/search.py --hidden 8       # the same sizes, the query's source clip hidden
    python benchmarks/search.py --quick          # the bundled examples/data clips, a few queries

Speed (same run, same queries): median ms per query of subsequence DTW (the baseline), the
certified search (``matchers.search``, its default :class:`CertifiedSettings`), the gap-tolerant
graph (``matchers.lng`` ``exact: false``) and the paper's graph (``paper: true``); printed as
the ratio sDTW / method, with the share of sDTW's top-10 end rows each returns ("kept"), whether
the certified search returned sDTW's matches exactly, and its counted work (sDTW's DP cells /
1.2 x coarse block cells + fine and seed DP cells). Databases: the augmented corpus of
``benchmarks/corpus.py`` (F_E^15, ``indexes.kdtree`` one thread); queries are random database
segments of 30, 64 and 90 frames. ``--hidden``: every augmented copy of the query's source clip
is removed from the database (only other performances count).

Quality (HDM05 cuts of ``../shared/data``, 30 Hz, F_E^15): query-by-example leaving one actor
out (each cut of the held-out actor a query against the other two actors' cuts; clips ranked by
their best match of 20; relevant = same class): mAP, P@5, queries without a result; and the
recall of sDTW's top-10 with the query's own clip hidden (1 s and 3 s random segments).
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from corpus import DATA, REPO, augmented_database

from mocapflow.framework import MotionDatabase
from mocapflow.framework.matching import SearchSpace
from mocapflow.framework.normalize import resample
from mocapflow.plugins.similarity.knn.end_effectors import EndEffectorFeatures
from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex
from mocapflow.plugins.similarity.search.certified import ExactStats, certified_sdtw
from mocapflow.plugins.similarity.search.fast import fast_sdtw
from mocapflow.plugins.similarity.search.lng import lazy_neighborhood_graph
from mocapflow.plugins.similarity.search.sdtw import subsequence_dtw


def search(q, space, count=10, stats=None):
    return certified_sdtw(q, space, count=count, stats=stats)


def fast(q, space, count=10, stats=None):
    return fast_sdtw(q, space, exact_search=certified_sdtw, count=count)


def graph(q, space, count=10, stats=None):
    return lazy_neighborhood_graph(q, space, count=count)


def paper(q, space, count=10, stats=None):
    return lazy_neighborhood_graph(q, space, count=count, gaps=0, propagate=0, fill=False)


def sdtw(q, space, count=10, stats=None):
    return subsequence_dtw(q, space, count=count)


METHODS = {"search (certified)": search, "search (fast)": fast, "lng graph": graph, "lng paper": paper}


def space_of(x, clip_id, frame) -> SearchSpace:
    return SearchSpace(clip_id, frame, KDTreeIndex(method="kdtree", workers=1).build(x), x)


def load_clips(files) -> tuple[MotionDatabase, np.ndarray]:
    from mocapflow.plugins.formats.asf_amc import read_amc

    db = MotionDatabase([resample(read_amc(f), 30.0) for f in files])
    return db, EndEffectorFeatures(joints=5).transform(db)


def segments(space: SearchSpace, length: int, count: int, rng) -> list[int]:
    """First rows of ``count`` random segments of ``length`` frames inside one clip."""
    out: list[int] = []
    while len(out) < count:
        s = int(rng.integers(0, space.n_rows - length))
        if (
            space.clip_id[s] == space.clip_id[s + length - 1]
            and space.frame[s + length - 1] - space.frame[s] == length - 1
        ):
            out.append(s)
    return out


def timed(fn, *args, **kw):
    t = time.perf_counter()
    res = fn(*args, **kw)
    return res, time.perf_counter() - t


def kept(res, ref) -> float:
    return len(set(res.end.tolist()) & set(ref.end.tolist())) / max(len(ref), 1)


def speed(space: SearchSpace, lengths, n_queries: int, rng, sources=None) -> None:
    """One table per query length (see the module doc); ``sources``: hide each query's source clip."""
    q0 = space.features[:8]
    for fn in (sdtw, *METHODS.values()):  # numba kernels loaded outside the timings
        fn(q0, space, count=2)
    print(
        f"  {space.n_rows:,} rows{', source hidden' if sources is not None else ''}; "
        f"load average {os.getloadavg()[0]:.2f}"
    )
    print(f"    {'query':>5} {'method':<22} {'ms':>8} {'sDTW/this':>9} {'kept':>5} {'identical':>9} {'work 1/x':>8}")
    for m in lengths:
        rows = {name: {"t": [], "kept": [], "same": [], "work": []} for name in METHODS}
        t_ref = []
        for s in segments(space, m, n_queries, rng):
            sp, q = space, space.features[s : s + m]
            if sources is not None:
                keep = sources[space.clip_id] != sources[space.clip_id[s]]
                sp = space_of(space.features[keep], space.clip_id[keep], space.frame[keep])
                search(q[:8], sp, count=2)  # the sub-space's block boxes, outside the timings
            ref, t = timed(sdtw, q, sp)
            t_ref.append(t)
            for name, fn in METHODS.items():
                st = ExactStats()
                res, t = timed(fn, q, sp, stats=st)
                r = rows[name]
                r["t"].append(t)
                r["kept"].append(kept(res, ref))
                r["same"].append(np.array_equal(res.end, ref.end) and np.array_equal(res.cost, ref.cost))
                r["work"].append(sp.n_rows / max(1.2 * st.coarse_blocks + st.columns + st.guess_columns, 1))
        tr = float(np.median(t_ref))
        print(f"    {m:>5} {'sDTW (baseline)':<22} {tr * 1e3:>8.2f} {1.0:>9.1f}")
        for name, r in rows.items():
            t = float(np.median(r["t"]))
            work = f"{np.median(r['work']):>8.1f}" if name.startswith("search") else ""
            print(
                f"    {m:>5} {name:<22} {t * 1e3:>8.2f} {tr / t:>9.1f} {np.mean(r['kept']):>5.2f} "
                f"{str(all(r['same'])):>9} {work}"
            )


def average_precision(ranked: list[bool], n_relevant: int) -> float:
    hits, total = 0, 0.0
    for r, ok in enumerate(ranked, 1):
        if ok:
            hits += 1
            total += hits / r
    return total / n_relevant if n_relevant else float("nan")


def qbe(db, x, actors, classes) -> None:
    """Query-by-example leaving one actor out (see the module doc)."""
    clip_id, frame = db.frame_ids
    acts = np.asarray(actors)
    stats = {name: {"ap": [], "p5": [], "empty": 0} for name in ("sdtw", *METHODS)}
    for actor in sorted(set(actors)):
        keep = acts[clip_id] != actor
        space = space_of(x[keep], clip_id[keep], frame[keep])
        in_db = np.unique(space.clip_id)
        for c in np.flatnonzero(acts == actor):
            q = x[db.offsets[c] : db.offsets[c + 1]]
            n_rel = sum(classes[o] == classes[c] for o in in_db)
            for name, fn in {"sdtw": sdtw, **METHODS}.items():
                res = fn(q, space, count=20)
                order = list(dict.fromkeys(int(space.clip_id[s]) for s in res.start))
                ranked = [classes[o] == classes[c] for o in order]
                st = stats[name]
                st["ap"].append(average_precision(ranked, n_rel))
                st["p5"].append(sum(ranked[:5]) / 5)
                st["empty"] += int(len(res) == 0 and n_rel > 0)
    print(f"  query-by-example, leave one actor out: {'method':<22} {'mAP':>6} {'P@5':>6} {'empty':>6}")
    for name, st in stats.items():
        print(f"    {name:<58} {np.nanmean(st['ap']):>6.3f} {np.mean(st['p5']):>6.3f} {st['empty']:>6d}")


def recall_hidden(db, x, lengths, n_queries: int, rng) -> None:
    """Recall of sDTW's top-10 with the query's own clip removed from the database."""
    clip_id, frame = db.frame_ids
    print(f"  recall of sDTW's top-10, own clip hidden ({n_queries} queries per length)")
    spaces: dict[int, SearchSpace] = {}
    for m in lengths:
        got = {name: [] for name in METHODS}
        for _ in range(n_queries):
            c = int(rng.choice([c for c in range(db.n_clips) if db.offsets[c + 1] - db.offsets[c] > m]))
            s = int(rng.integers(db.offsets[c], db.offsets[c + 1] - m + 1))
            if c not in spaces:
                keep = clip_id != c
                spaces[c] = space_of(x[keep], clip_id[keep], frame[keep])
            ref = sdtw(x[s : s + m], spaces[c])
            for name, fn in METHODS.items():
                got[name].append(kept(fn(x[s : s + m], spaces[c]), ref))
        for name, r in got.items():
            print(f"    {m:>4} frames  {name:<22} {np.mean(r):>6.3f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the bundled examples/data clips, a few queries")
    ap.add_argument("--sizes", type=int, nargs="*", default=[380_813, 1_038_388], help="database sizes in frames")
    ap.add_argument("--queries", type=int, default=6, help="queries per length")
    ap.add_argument("--hidden", type=int, default=0, help="speed with the query's source hidden, this many queries")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    print("global search vs subsequence DTW; F_E^15; kd-tree; one thread")
    if args.quick:
        db, x = load_clips(sorted((REPO / "examples" / "data" / "cmu").glob("*/*.amc")))
        speed(space_of(x, *db.frame_ids), (30, 64), 2, rng)
        recall_hidden(db, x, (30,), 2, rng)
        return 0
    for n in args.sizes:
        db = augmented_database(n, fps=30)
        x = EndEffectorFeatures(joints=5).transform(db)
        space = space_of(x, *db.frame_ids)
        if args.hidden:  # each clip's source (augmented copies are named <source>[_mirrored][_v<n>])
            src = np.array([re.sub(r"(_mirrored)?(_v\d+)?$", "", m.name) for m in db])
            speed(space, (30, 90), args.hidden, rng, sources=src)
        else:
            speed(space, (30, 64, 90), args.queries, rng)
    files = sorted(DATA.glob("hdm05/amc/*/*.amc"))
    if files:
        db, x = load_clips(files)
        qbe(db, x, [f.parent.name for f in files], [f.stem.split("_")[2] for f in files])
        recall_hidden(db, x, (30, 90), 32, rng)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
