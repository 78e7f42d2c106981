"""The certified search's parts against alternatives, in one process (A/B, process CPU time).

    python benchmarks/certified_ab.py --size 380813 --kernel-old 2823527         # coarse kernel A/B
    python benchmarks/certified_ab.py --size 1038388 --seed-eps 0 0.5 1 2          # the seeds' kd-tree eps
    python benchmarks/certified_ab.py --size 1038388 --seed-vote 0 2 4             # voted seed windows
    python benchmarks/certified_ab.py --size 380813 --levels 512/64/16/4 512/128/32/8
    python benchmarks/certified_ab.py --size 380813 --levels 512/64/16/4 512/64/16s3/4s2  # subspace cells
    ... --hidden                                                                    # the query's source hidden
    python benchmarks/certified_ab.py --quick       # 60,000 rows, 2 queries, two hierarchies: a smoke run

Database: ``benchmarks/corpus.py``'s augmented corpus at ``--size`` frames, F_E^15
(``features.end_effectors`` joints 5), ``indexes.kdtree``; queries: random segments of 30, 64
and 90 frames, with ``--hidden`` every augmented copy of the query's source clip removed (its
own kd-tree), as ``benchmarks/matching.py --hidden``. Timed in process CPU seconds (the
kernels are single-threaded; wall time on the shared machine swings by +-30 %), runs
alternating in order; printed per query length: medians over the queries.

* ``--kernel-old REV``: every ``coarse_bounds`` call of the working tree's certified searches
  is captured and replayed through commit ``REV``'s ``_coarse_kernels.coarse_bounds`` and the
  working tree's; old/new time ratio per query (> 1: the working tree is faster), and whether
  the bounds agree (relative 1e-4).
* ``--seed-eps``: the whole search with ``exact.SEED_EPS`` set to each value (results checked
  identical): ms, counted work (sDTW cells / (1.2 x coarse block cells + fine and seed DP
  cells)) and ``tau``.
* ``--seed-slope``: the same with ``exact.SEED_SLOPE`` (the seed windows' width) set to each value.
* ``--seed-k`` / ``--seed-frames``: the same with ``exact.SEED_K`` (neighbours per seed frame,
  times ``count``) / ``exact.SEED_FRAMES`` (query frames searched) set to each value.
* ``--seed-vote``: the same with ``exact.SEED_VOTE`` set to each value (voted seed windows).
* ``--subspace-from``: the same with ``exact.SUBSPACE_FROM`` (the share of a level's blocks in
  play from which it uses subspace cells; 0: always, above 1: never) set to each value.
* ``--levels``: the whole search with each block hierarchy; time ratio to the first one. A
  level ``16s3`` has local subspace cells with a basis of 3 directions (``subspace``), plain
  ``16`` boxes.

No assertions beyond identical results: the figures are the output.
"""
from __future__ import annotations

import argparse
import importlib
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))


def database(n: int):
    from corpus import augmented_database

    from mocapflow.plugins.similarity.knn.end_effectors import EndEffectorFeatures

    db = augmented_database(n, fps=30)
    x = np.ascontiguousarray(EndEffectorFeatures(joints=5).transform(db))
    clip_id, frame = db.frame_ids
    src = np.array([re.sub(r"(_mirrored)?(_v\d+)?$", "", m.name) for m in db])[clip_id]
    return x, clip_id, frame, src


def spaces(x, clip_id, frame, src, lengths, n_queries, hidden, rng):
    """(query, space) pairs per length; with ``hidden`` each query's source clip removed."""
    from mocapflow.framework.matching import SearchSpace
    from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex

    def space(keep=None):
        if keep is None:
            return SearchSpace(clip_id, frame, KDTreeIndex(method="kdtree", workers=1).build(x), x)
        xs = np.ascontiguousarray(x[keep])
        return SearchSpace(clip_id[keep], frame[keep], KDTreeIndex(method="kdtree", workers=1).build(xs), xs)

    full = None if hidden else space()
    out = {}
    for m in lengths:
        while len(out.setdefault(m, [])) < n_queries:
            s = int(rng.integers(0, len(x) - m))
            if clip_id[s] == clip_id[s + m - 1] and frame[s + m - 1] - frame[s] == m - 1:
                out[m].append((x[s : s + m], full if full is not None else space(src != src[s])))
    return out


def old_coarse(rev: str, where: Path):
    pkg = where / "old_coarse"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    src = subprocess.run(["git", "show", f"{rev}:plugins/similarity/_coarse_kernels.py"], cwd=ROOT, check=True,
                         capture_output=True, text=True).stdout
    (pkg / "_coarse_kernels.py").write_text(src.replace("from ._dtw_kernels import",
                                                         "from mocapflow.plugins.similarity.search._dtw_kernels import"))
    sys.path.insert(0, str(where))
    return importlib.import_module("old_coarse._coarse_kernels").coarse_bounds


def cpu(fn, *args):
    t = time.process_time()
    out = fn(*args)
    return time.process_time() - t, out


def kernel_ab(queries, rev, rounds):
    import mocapflow.plugins.similarity.search._coarse_kernels as ck
    from mocapflow.plugins.similarity.search.exact import certified_sdtw

    new = ck.coarse_bounds
    with tempfile.TemporaryDirectory() as tmp:
        old = old_coarse(rev, Path(tmp))
        for m, qs in queries.items():
            ratios, agree = [], True
            for q, sp in qs:
                calls = []
                ck.coarse_bounds = lambda *a: (calls.append(a), new(*a))[1]
                try:
                    certified_sdtw(q, sp, count=10)
                finally:
                    ck.coarse_bounds = new
                for a in calls:
                    agree &= bool(np.allclose(old(*a), new(*a), rtol=1e-4, atol=1e-5))  # both compiled
                t = {"old": 0.0, "new": 0.0}
                for r in range(rounds):
                    for side in ("old", "new") if r % 2 == 0 else ("new", "old"):
                        for a in calls:
                            t[side] += cpu(old if side == "old" else new, *a)[0]
                ratios.append(t["old"] / max(t["new"], 1e-12))
                tn = t["new"] / rounds
            print(f"  {m} frames: coarse_bounds old/new median {np.median(ratios):.2f} (per query "
                  f"{', '.join(f'{r:.2f}' for r in ratios)}; last query new {tn * 1e3:.2f} ms); bounds agree: {agree}")


def level_kw(spec: str) -> dict:
    """``certified_sdtw`` keywords of a hierarchy ``512/64/16s3/4s2``: block sizes, and basis sizes (0: boxes)."""
    parts = [v.partition("s") for v in spec.split("/")]
    return {"levels": tuple(int(a) for a, _, _ in parts), "subspace": tuple(int(b or 0) for _, _, b in parts)}


def whole(queries, settings, apply, label, rounds):
    import mocapflow.plugins.similarity.search.exact as ex

    for m, qs in queries.items():
        rows = {s: [] for s in settings}
        for q, sp in qs:
            for s in settings:  # compile, and the space's block boxes, outside the timings
                apply(ex, s)
                ex.certified_sdtw(q[:8], sp, count=3, subspace_from=0, **(level_kw(s) if label == "levels" else {}))
            ref = None
            for r in range(rounds):
                for s in settings if r % 2 == 0 else settings[::-1]:
                    apply(ex, s)
                    st = ex.ExactStats()
                    kw = level_kw(s) if label == "levels" else {}
                    t, got = cpu(lambda: ex.certified_sdtw(q, sp, count=10, stats=st, **kw))
                    ref = got if ref is None else ref
                    assert np.array_equal(got.cost, ref.cost) and np.array_equal(got.end, ref.end)
                    work = sp.n_rows / max(1.2 * st.coarse_blocks + st.columns + st.guess_columns, 1)
                    rows[s].append((t, work, st.tau))
        base = np.median([t for t, _, _ in rows[settings[0]]])
        for s in settings:
            v = np.array(rows[s])
            name = s if label == "levels" else f"{label} {s:g}"
            print(f"  {m} frames: {name:<22} {np.median(v[:, 0]) * 1e3:7.2f} ms (first / this {base / np.median(v[:, 0]):.2f}) "
                  f"work 1/{np.median(v[:, 1]):.1f} tau median {np.median(v[:, 2]):.2f}")


#: whole-search A/Bs of one module constant of ``exact``: (option dest, constant)
SETTINGS = (("seed_eps", "SEED_EPS"), ("seed_vote", "SEED_VOTE"), ("seed_slope", "SEED_SLOPE"),
            ("seed_k", "SEED_K"), ("seed_frames", "SEED_FRAMES"), ("subspace_from", "SUBSPACE_FROM"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="60,000 rows, 2 queries per length, 2 rounds")
    ap.add_argument("--size", type=int, default=380_813)
    ap.add_argument("--queries", type=int, default=4, help="per query length")
    ap.add_argument("--hidden", action="store_true", help="the query's source clip hidden")
    ap.add_argument("--kernel-old", default=None, help="git revision of the baseline coarse kernel")
    ap.add_argument("--seed-eps", type=float, nargs="*", default=None)
    ap.add_argument("--seed-vote", type=int, nargs="*", default=None,
                    help="exact.SEED_VOTE values (voted seed windows first, x count; 0 = all windows)")
    ap.add_argument("--seed-slope", type=float, nargs="*", default=None, help="exact.SEED_SLOPE values")
    ap.add_argument("--seed-k", type=int, nargs="*", default=None, help="exact.SEED_K values")
    ap.add_argument("--seed-frames", type=int, nargs="*", default=None, help="exact.SEED_FRAMES values")
    ap.add_argument("--subspace-from", type=float, nargs="*", default=None, help="exact.SUBSPACE_FROM values")
    ap.add_argument("--levels", nargs="*", default=None, help="block hierarchies, e.g. 512/64/16/4")
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    if args.quick:
        args.size, args.queries, args.rounds = 60_000, 2, 2
        if not (args.kernel_old or args.levels or any(getattr(args, flag) for flag, _ in SETTINGS)):
            args.levels = ["512/64/16/4", "256/32/8"]
    x, clip_id, frame, src = database(args.size)
    queries = spaces(x, clip_id, frame, src, (30, 64, 90), args.queries, args.hidden, np.random.default_rng(args.seed))
    print(f"{args.size:,} rows, {'source hidden' if args.hidden else 'own source'}, {args.queries} queries per length; "
          f"load average {open('/proc/loadavg').read().split()[0]}")
    if args.kernel_old:
        kernel_ab(queries, args.kernel_old, args.rounds)
    for flag, attr in SETTINGS:
        if getattr(args, flag):
            whole(queries, list(getattr(args, flag)), lambda ex, s, attr=attr: setattr(ex, attr, s),
                  flag.replace("_", " "), max(2, args.rounds // 2))
    if args.levels:
        whole(queries, list(args.levels), lambda ex, s: None, "levels", max(2, args.rounds // 2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
