"""The ceiling of any exact, DP-verifying search: rows and cells on a path of cost <= tau (issue 13).

    python benchmarks/certified_ceiling.py                  # counts: 380,813 and 1,038,388 rows (quality run)
    python benchmarks/certified_ceiling.py --save c.json    # ... and keep the oracle ranges
    python benchmarks/certified_ceiling.py --timing c.json  # time the fine DP over them (timing run, lock)
    python benchmarks/certified_ceiling.py --quick          # 60,000 rows, 2 queries per length

Queries are ``benchmarks/matching.py``'s (same ``--seed``, sizes in the same order, the same
draws: one 8-frame warm-up segment, then ``--queries`` segments of 30, 64, 90 frames per
size), so the figures belong to the issue's command ``matching.py --sizes 380813 1038388
--queries 4 --exact 4 --certified-only``. Per query, ``tau`` = sDTW's own ``count``-th
match cost (count 10, min_span 0.5, the defaults), then the float64 forward + backward
recurrences over every cell (``_ceiling_kernels.through_cell_rows``; its forward cost is
checked against ``subsequence_dtw`` on the matches) give

* **oracle rows**: rows ``j`` with ``min_i F + G - d <= tau`` (the rows any exact method
  verifying by DP must compute: a pruned row on a path <= tau could change a match);
* **oracle cells**: cells with ``F + G - d <= tau`` (a cell-pruned DP's minimum);
* **block-4 oracle**: rows of the default's 4-row blocks holding an oracle row (the finest
  level with an exact per-block bound, the best any 4-row block bound can do);
* the default's (``matchers.lng``, certified) fine DP rows and coarse cells, and its ``tau``;

and the ceilings ``n m / cells`` and ``n / rows`` (sDTW's cells over the oracle's). ``tau``
is widened by 1e-5 relative: sDTW accumulates float32 distances, the oracle float64 ones.

``--timing FILE`` (after a ``--save FILE`` run) times, in process CPU seconds, alternating,
median of ``--rounds``: ``sdtw_forward`` over all rows, ``sdtw_ranges_compact`` over exactly
the oracle rows (the fine DP of a perfect bound, free of charge), the seeds' step that
supplies the default's ``tau``, and the default search; the time ceilings are sDTW / oracle
DP and sDTW / (oracle DP + seeds).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

SLACK = 1.0 + 1e-5
#: the oracle's rows also at these multiples of tau: what a bound within (1 - 1/w) of the truth keeps at best
WIDER = (1.1, 1.25, 1.5)
LENGTHS = (30, 64, 90)


def data(n: int):
    """(features float32 (n, 15), clip_id, frame), the features cached beside the corpus."""
    from corpus import CACHE, augmented_database, cache_path

    db = augmented_database(n, fps=30)
    clip_id, frame = db.frame_ids
    f = cache_path(n, 30.0, 0, CACHE) / "features_fe15_j5.npy"
    if f.is_file():
        x = np.load(f)
    else:
        from mocapflow.plugins.similarity.knn.end_effectors import EndEffectorFeatures

        x = np.ascontiguousarray(EndEffectorFeatures(joints=5).transform(db), np.float32)
        np.save(f, x)
    return x, np.asarray(clip_id), np.asarray(frame)


def space_of(x, clip_id, frame, index=False):
    from mocapflow.framework.matching import SearchSpace
    from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex

    idx = KDTreeIndex(method="kdtree", workers=1).build(x) if index else None
    return SearchSpace(clip_id, frame, idx, x)


def draw_queries(sizes, n_queries, seed):
    """``{size: {m: [first row, ...]}}``: matching.py's draws (its rng runs on through the sizes)."""
    from matching import random_segments

    rng = np.random.default_rng(seed)
    out = {}
    for n in sizes:
        x, cid, fr = data(n)
        sp = space_of(x, cid, fr)
        random_segments(sp, 8, 1, rng)  # matching.py's warm-up query
        out[n] = {m: random_segments(sp, m, n_queries, rng) for m in LENGTHS}
    return out


def oracle(q, sp, tau):
    """(row_min (n,), cells (n,), end_cost (n,)) of the query, float64."""
    from _ceiling_kernels import through_cell_rows

    return through_cell_rows(np.asarray(q, np.float64), sp.features, sp.continues, tau * SLACK)


def row_ranges(mask):
    from mocapflow.plugins.similarity.search.exact import block_ranges

    return block_ranges(mask)


def quality(sizes, picks, save):
    from mocapflow.plugins.similarity.search import exact
    from mocapflow.plugins.similarity.search.matcher_base import block_boxes_of
    from mocapflow.plugins.similarity.search.sdtw import subsequence_dtw

    saved = []
    hdr = (f"{'rows':>9} {'m':>3} {'tau':>7} {'seed/tau':>8} {'oracle rows':>11} {'cells':>8} {'blk4 rows':>9} "
           f"{'dflt rows':>9} {'dflt coarse':>11} {'ceil cells':>10} {'ceil rows':>9} {'ceil blk4':>9} {'dflt work':>9}")
    print(hdr)
    for n in sizes:
        x, cid, fr = data(n)
        sp = space_of(x, cid, fr, index=True)
        b4 = block_boxes_of(sp, 4)[0]
        block_of = np.repeat(np.arange(len(b4) - 1), np.diff(b4))
        level_sizes = [len(block_boxes_of(sp, b)[1]) for b in exact.LEVELS]
        for m in LENGTHS:
            med = []
            for s in picks[n][m]:
                q = x[s : s + m]
                ref = subsequence_dtw(q, sp, count=10)
                tau = float(ref.cost[-1])
                row_min, cells, end_cost = oracle(q, sp, tau)
                e = ref.end - 1
                err = float(np.max(np.abs(end_cost[e] - ref.cost) / np.maximum(ref.cost, 1e-12)))
                assert err < 1e-5, f"oracle forward differs from sDTW by {err:.2e} relative"
                alive = row_min <= tau * SLACK
                nb4 = int(np.diff(b4)[np.unique(block_of[alive])].sum()) if alive.any() else 0
                st = exact.ExactStats()
                got = exact.certified_sdtw(q, sp, count=10, stats=st)
                assert np.array_equal(got.cost, ref.cost) and np.array_equal(got.end, ref.end)
                rows, ncell = int(alive.sum()), int(cells.sum())
                work = 1.2 * st.coarse_blocks + st.columns + st.guess_columns
                r = dict(n=n, m=m, s=int(s), tau=tau, seed_tau=float(st.tau), rows=rows / n, cells=ncell / (n * m),
                         blk4=nb4 / n, dflt_rows=st.columns / n, dflt_coarse=1.2 * st.coarse_blocks / n,
                         ceil_cells=n * m / max(ncell, 1), ceil_rows=n / max(rows, 1), ceil_blk4=n / max(nb4, 1),
                         dflt_work=n / max(work, 1), ranges=row_ranges(alive).tolist(),
                         seed_rows=float(np.mean(row_min <= st.tau * SLACK)),
                         wide=[float(np.mean(row_min <= w * tau * SLACK)) for w in WIDER],
                         levels=[b / nl for b, nl in zip(st.level_blocks, level_sizes[1:])])
                saved.append(r)
                med.append(r)
                print(f"{n:>9,} {m:>3} {tau:>7.2f} {st.tau / tau:>8.3f} {100 * r['rows']:>10.3f}% "
                      f"{100 * r['cells']:>7.3f}% {100 * r['blk4']:>8.3f}% {100 * r['dflt_rows']:>8.2f}% "
                      f"{100 * r['dflt_coarse']:>10.2f}% {r['ceil_cells']:>9.0f}x {r['ceil_rows']:>8.0f}x "
                      f"{r['ceil_blk4']:>8.0f}x {r['dflt_work']:>8.1f}x", flush=True)
                print(f"{'':>14} rows at seed tau {100 * r['seed_rows']:.3f}%, at "
                      + ", ".join(f"{w:g} tau {100 * v:.3f}%" for w, v in zip(WIDER, r["wide"]))
                      + "; default's levels evaluated (of their blocks) "
                      + "/".join(f"{100 * v:.0f}%" for v in r["levels"]), flush=True)
            print(f"{n:>9,} {m:>3} median: oracle rows {100 * np.median([r['rows'] for r in med]):.3f}%, "
                  f"ceiling (rows) {np.median([r['ceil_rows'] for r in med]):.0f}x, (cells) "
                  f"{np.median([r['ceil_cells'] for r in med]):.0f}x, (4-row blocks) "
                  f"{np.median([r['ceil_blk4'] for r in med]):.0f}x; default work 1/"
                  f"{np.median([r['dflt_work'] for r in med]):.1f}", flush=True)
    if save:
        Path(save).write_text(json.dumps(saved))


def cpu(fn, *args):
    t = time.process_time()
    fn(*args)
    return time.process_time() - t


def timing(path, rounds):
    from mocapflow.plugins.similarity.search import exact
    from mocapflow.plugins.similarity.search._dtw_kernels import sdtw_forward, sdtw_ranges_compact
    from mocapflow.framework.matching import min_frames_of

    saved = json.loads(Path(path).read_text())
    print(f"load average {open('/proc/loadavg').read().split()[0]}; process CPU ms, median of {rounds} rounds")
    print(f"{'rows':>9} {'m':>3} {'sDTW ms':>8} {'oracle DP':>9} {'seeds':>6} {'default':>8} {'ceil DP':>8} "
          f"{'ceil +seeds':>11} {'default x':>9} {'ns/cell sDTW':>12} {'oracle':>7}")
    for n in sorted({r["n"] for r in saved}):
        x, cid, fr = data(n)
        sp = space_of(x, cid, fr, index=True)
        cs = exact.clip_starts(sp)
        exact.certified_sdtw(x[:8], sp, count=3)  # compile, block boxes
        for m in LENGTHS:
            res = []
            for r in [r for r in saved if r["n"] == n and r["m"] == m]:
                q = np.ascontiguousarray(x[r["s"] : r["s"] + m])
                qt = np.ascontiguousarray(q.T)
                rg = np.asarray(r["ranges"], np.int64).reshape(-1, 2)
                runs = {
                    "sdtw": lambda: sdtw_forward(qt, x, cs),
                    "oracle": lambda: sdtw_ranges_compact(qt, x, cs, rg),
                    "seeds": lambda: exact._seed_tau(q, qt, sp, 10, None, "cost", min_frames_of(0.5, m),
                                                     exact.ExactStats()),
                    "default": lambda: exact.certified_sdtw(q, sp, count=10),
                }
                t = {k: [] for k in runs}
                for i in range(rounds):
                    for k in (list(runs) if i % 2 == 0 else list(runs)[::-1]):
                        t[k].append(cpu(runs[k]))
                t = {k: float(np.median(v)) for k, v in t.items()}
                res.append(t)
                cells = max(int((rg[:, 1] - rg[:, 0]).sum()) * m, 1)
                print(f"{n:>9,} {m:>3} {t['sdtw'] * 1e3:>8.2f} {t['oracle'] * 1e3:>9.3f} {t['seeds'] * 1e3:>6.2f} "
                      f"{t['default'] * 1e3:>8.2f} {t['sdtw'] / max(t['oracle'], 1e-7):>7.0f}x "
                      f"{t['sdtw'] / (t['oracle'] + t['seeds']):>10.1f}x {t['sdtw'] / t['default']:>8.1f}x "
                      f"{t['sdtw'] * 1e9 / (n * m):>12.2f} {t['oracle'] * 1e9 / cells:>7.2f}", flush=True)

            def med(f, res=res):
                return float(np.median([f(t) for t in res]))

            print(f"{n:>9,} {m:>3} median: ceiling (oracle DP) {med(lambda t: t['sdtw'] / max(t['oracle'], 1e-7)):.0f}x, "
                  f"(oracle DP + seeds) {med(lambda t: t['sdtw'] / (t['oracle'] + t['seeds'])):.1f}x, "
                  f"default {med(lambda t: t['sdtw'] / t['default']):.1f}x (ratio of medians, as matching.py: "
                  f"{med(lambda t: t['sdtw']) / med(lambda t: t['default']):.1f}x); load average "
                  f"{open('/proc/loadavg').read().split()[0]}", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one 60,000-row database, 2 queries per length")
    ap.add_argument("--sizes", type=int, nargs="*", default=None, help="database sizes, in matching.py's order")
    ap.add_argument("--queries", type=int, default=None, help="per length (default 4, matching.py's issue command)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--save", default=None, help="write the per-query figures and oracle ranges (JSON)")
    ap.add_argument("--timing", default=None, help="time the fine DP over a saved file's oracle ranges")
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args(argv)
    if args.timing:
        timing(args.timing, args.rounds)
        return 0
    sizes = args.sizes or ([60_000] if args.quick else [380_813, 1_038_388])
    n_q = args.queries or (2 if args.quick else 4)
    picks = draw_queries(sizes, n_q, args.seed)
    print(f"oracle of exact sDTW (count 10, min_span 0.5), F_E^15, {n_q} queries per length; shares of all rows / cells")
    quality(sizes, picks, args.save)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
