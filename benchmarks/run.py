"""Run the benchmarks a maintainer reruns: one per capability.

    python benchmarks/run.py --list              # every benchmark with what it measures
    python benchmarks/run.py NAME [ARGS...]      # one, ARGS passed through (e.g. --quick)
    python benchmarks/run.py --all --quick       # every one on its tiny input (seconds each)

Each ``benchmarks/<name>.py`` runs its real measurement on ``../shared/data`` and prints
ratios against a baseline measured in the same run; with ``--quick`` it runs in about 30 s on
two cores on the bundled ``examples/data`` or synthetic motion (``tests/test_benchmarks.py``
runs every one that way so none rots).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent

#: name -> what it measures (the script is ``benchmarks/<name>.py``).
BENCHMARKS: dict[str, str] = {
    "cleaning": "cleaners.mdm: detection and repair quality on injected errors, and its speed",
    "search": "the default global search (certified subsequence DTW): query time and exactness against plain sDTW",
    "knn": "kNN indexes (kd-tree, HNSW, sharded): build and query time, recall against brute force",
    "reconstruct": "pose reconstruction from sparse markers: error and time per frame",
    "fat_graph": "fat graph construction and random walks: time and transitions",
    "ingest": "format readers (AMC, BVH): read + forward kinematics against a plain line-by-line reference",
    "fuzz_parsers": "mutational fuzzing of the format readers against slow reference readers",
    "relational": "relational features, inverted indexes and the paper's queries: fidelity, build and query time",
    "templates": "motion templates and mode auto: leave-one-actor-out quality, query time against the full-rate search",
    "report": "mocapflow report: page weight and load time in headless Chromium against a JSON baseline",
    "startup": "command start-up against `import numpy`, and the quickstart's cold first run",
    "first_run": "the first run after an install (empty numba cache) against the warm run: quickstart, clean",
    "scale": "scale-out: --jobs 2 and the Dask executor against --jobs 1, the sharded kNN index",
    "search_scale": "global search at library scale (1 M-10 M rows): exact and fast modes against sDTW, source hidden",
    "build_scale": "building a large library's workspace (ingest, F_E^15, kd-tree): peak RSS, bytes per frame, minutes",
}


def run(name: str, args: list[str]) -> int:
    script = HERE / f"{name}.py"
    if not script.is_file():
        print(f"no benchmark script {script}", file=sys.stderr)
        return 2
    return subprocess.run([sys.executable, str(script), *args]).returncode


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], usage="%(prog)s (--list | --all [--quick] | NAME [ARGS...])"
    )
    ap.add_argument("name", nargs="?", help="the benchmark to run")
    ap.add_argument("--list", action="store_true", help="list every benchmark with what it measures")
    ap.add_argument("--all", action="store_true", help="run every benchmark")
    ap.add_argument("--quick", action="store_true", help="pass --quick: the tiny input (about 30 s each)")
    args, rest = ap.parse_known_args(argv)
    rest = (["--quick"] if args.quick else []) + rest
    if args.list:
        for name, what in BENCHMARKS.items():
            print(f"{name:<13} {what}")
        return 0
    if args.all:
        failed = []
        for name in BENCHMARKS:
            print(f"\n=== {name} ===", flush=True)
            t0 = time.perf_counter()
            rc = run(name, rest)
            print(f"=== {name}: exit {rc} in {time.perf_counter() - t0:.1f} s ===", flush=True)
            if rc:
                failed.append(name)
        print(
            f"\n{len(BENCHMARKS) - len(failed)} of {len(BENCHMARKS)} passed" + (f"; failed: {failed}" if failed else "")
        )
        return 1 if failed else 0
    if args.name not in BENCHMARKS:
        ap.error(f"unknown benchmark {args.name!r}; known: {', '.join(BENCHMARKS)}")
    return run(args.name, rest)


if __name__ == "__main__":
    raise SystemExit(main())
