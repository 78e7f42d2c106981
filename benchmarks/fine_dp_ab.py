"""The fine subsequence-DTW kernels against an earlier commit's, in one process (A/B).

    nice -n 10 python benchmarks/fine_dp_ab.py --old c87fd00~1

``sdtw_forward`` and ``sdtw_ranges_compact`` of the working tree and of commit ``--old``
(its ``_dtw_kernels.py`` and ``_coarse_kernels.py``, written to a temporary package and
imported side by side) run on the F_E^15 features of the 380,813-frame benchmark corpus
(``~/.cache/mocapflow-bench``, built by ``benchmarks/matching.py``; a clip start every ~165
rows), queries of 30, 64 and 90 frames, the ranged DP over ~325 ranges of 200 rows and
~47 of 2,000. Runs alternate old, new / new, old; timed in process CPU seconds (the
kernels are single-threaded; wall time on a loaded machine swings by +-30 %); printed: min
and median old/new ratios (> 1: the working tree is faster), the load average, and whether
the outputs are bit-identical. No assertions.
"""
from __future__ import annotations

import argparse
import importlib
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FEATURES = Path.home() / ".cache" / "mocapflow-bench" / "features_380813" / "F_E15.npy"


def old_kernels(rev: str, where: Path):
    """``(sdtw_forward, sdtw_ranges_compact)`` of commit ``rev``, imported from a copy in ``where``."""
    pkg = where / "old_fine_dp"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    for name in ("_dtw_kernels.py", "_coarse_kernels.py"):
        src = subprocess.run(["git", "show", f"{rev}:plugins/similarity/{name}"], cwd=ROOT, check=True,
                             capture_output=True, text=True).stdout
        (pkg / name).write_text(src)
    sys.path.insert(0, str(where))
    dtw = importlib.import_module("old_fine_dp._dtw_kernels")
    coarse = importlib.import_module("old_fine_dp._coarse_kernels")
    return dtw.sdtw_forward, getattr(dtw, "sdtw_ranges_compact", None) or coarse.sdtw_ranges_compact


def timed(f, *args, reps=2):
    t = time.process_time()  # CPU time: on a shared machine far steadier than wall time
    for _ in range(reps):
        out = f(*args)
    return (time.process_time() - t) / reps, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", required=True, help="git revision of the baseline kernels")
    ap.add_argument("--rounds", type=int, default=12, help="alternating rounds (default 12)")
    ap.add_argument("--quick", action="store_true", help="3 rounds: a smoke run")
    args = ap.parse_args()
    from mocapflow.plugins.similarity.search._dtw_kernels import sdtw_forward, sdtw_ranges_compact

    x = np.ascontiguousarray(np.load(FEATURES).astype(np.float32))
    n = len(x)
    rng = np.random.default_rng(0)
    clip_start = np.zeros(n, bool)
    clip_start[0] = True
    clip_start[rng.choice(n, n // 165, replace=False)] = True
    with tempfile.TemporaryDirectory() as tmp:
        old = dict(zip(("forward", "ranges"), old_kernels(args.old, Path(tmp))))
        new = {"forward": sdtw_forward, "ranges": sdtw_ranges_compact}
        print(f"{n:,} rows x {x.shape[1]}; old {args.old}; load average {open('/proc/loadavg').read().split()[0]}")
        identical = True
        for m in (30, 64, 90):
            s = int(rng.integers(0, n - m))
            qt = np.ascontiguousarray((x[s : s + m] + rng.normal(0, 0.1, (m, x.shape[1]))).astype(np.float32).T)
            for label, kernel, width, count in (("sdtw_forward", "forward", None, None),
                                                ("sdtw_ranges_compact", "ranges", 200, 400),
                                                ("sdtw_ranges_compact", "ranges", 2000, 60)):
                call = (qt, x, clip_start)
                if width is not None:
                    a = np.sort(rng.choice(n - width - 1, count, replace=False))
                    keep = [0]  # disjoint ranges
                    for i in range(1, len(a)):
                        if a[i] >= a[keep[-1]] + width:
                            keep.append(i)
                    call += (np.stack([a[keep], a[keep] + width], axis=1).astype(np.int64),)
                    label = f"{label} {len(keep)} x {width} rows"
                t = {"old": [], "new": []}
                outs = {side: kernels[kernel](*call) for side, kernels in (("old", old), ("new", new))}  # compiled
                for r in range(3 if args.quick else args.rounds):
                    for side in ("old", "new") if r % 2 == 0 else ("new", "old"):
                        dt, outs[side] = timed((old if side == "old" else new)[kernel], *call)
                        t[side].append(dt)
                identical &= all(np.array_equal(u, v) for u, v in zip(outs["old"], outs["new"]))
                mo, mn = np.min(t["old"]), np.min(t["new"])
                do, dn = np.median(t["old"]), np.median(t["new"])
                print(f"  m={m:3d} {label:40s} old {do * 1e3:7.1f} ms  new {dn * 1e3:7.1f} ms  "
                      f"old/new min {mo / mn:.3f} median {do / dn:.3f}")
    print(f"outputs bit-identical: {identical}; load average {open('/proc/loadavg').read().split()[0]}")


if __name__ == "__main__":
    main()
