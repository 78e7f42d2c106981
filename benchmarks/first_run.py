"""The first run after an install: the quickstart and the one-liner ``mocapflow clean`` with
an empty numba cache (every kernel compiles) against the same run warm, in the same process
tree, so the ratio holds on a loaded machine too.

Each repetition gets a new empty cache (``NUMBA_CACHE_DIR`` = a new temporary folder) and a
new workspace: cold run, then warm run (``--force``: everything recomputes, the kernels load
from the cache). Printed: min and median over the repetitions of cold and warm wall seconds,
their ratio, the compilation time (cold - warm), the kernels in the cache, and the target
check ``cold <= 1.5 x warm + 10 s``.

    python benchmarks/first_run.py --quick   # a one-clip pipeline, one repetition (~25 s)
    python benchmarks/first_run.py           # quickstart and clean, 3 repetitions
    python benchmarks/first_run.py --kernels --only quickstart   # compile seconds per kernel
    /work/cpulock python benchmarks/first_run.py --only quickstart --repeat 3
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from startup import CLI, ROOT, _cache_counts, _pipeline

TINY = """name: first-run-tiny
workspace: {ws}
steps:
  motions: {{uses: formats.load, with: {{paths: ["{take}"], fps: 30}}}}
  summary: {{uses: analyses.clip_summary, input: motions}}
  fe15: {{uses: features.end_effectors, input: motions, with: {{joints: 5}}}}
  tree: {{uses: indexes.kdtree, input: fe15}}
"""


def _timed(cmd: list[str], cache: Path, cwd: Path) -> float:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "MOCAPFLOW_PROGRESS": "0"}
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=str(cwd))
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({res.returncode}):\n{res.stdout[-2000:]}\n{res.stderr[-2000:]}")
    return wall


def _case_commands(case: str, tmp: Path) -> tuple[list[str], list[str]]:
    """(cold command, warm command) of a case, run in ``tmp``."""
    py = sys.executable
    if case == "quickstart":
        p = str(_pipeline(ROOT, tmp))
        run = [py, "-c", CLI, "--no-entry-points", "run", p]
        return run, [*run, "--force"]
    if case == "tiny":
        p = tmp / "tiny.yaml"
        p.write_text(TINY.format(ws=tmp / "ws", take=ROOT / "examples/data/cmu/35/35_01.amc"))
        run = [py, "-c", CLI, "--no-entry-points", "run", str(p)]
        return run, [*run, "--force"]
    if case == "clean":
        take = ROOT / "examples/data/cmu/16/16_15.amc"
        cmd = [py, "-c", CLI, "clean", str(take), "--output", str(tmp / "cleaned.bvh")]
        return cmd, cmd
    raise SystemExit(f"unknown case {case!r}")


def measure(case: str, repeat: int) -> dict[str, float]:
    colds, warms, variants = [], [], 0
    for _ in range(repeat):
        with tempfile.TemporaryDirectory(prefix="mocapflow-first-run-") as tmp_s:
            tmp = Path(tmp_s)
            cache = tmp / "numba-cache"
            cold_cmd, warm_cmd = _case_commands(case, tmp)
            colds.append(_timed(cold_cmd, cache, tmp))
            warms.append(_timed(warm_cmd, cache, tmp))
            variants = _cache_counts(cache)[1]
    cold, warm = statistics.median(colds), statistics.median(warms)
    limit = 1.5 * warm + 10.0
    print(
        f"  {case:<11} cold min {min(colds):6.1f} median {cold:6.1f} s | warm min {min(warms):6.1f} "
        f"median {warm:6.1f} s | cold/warm {cold / warm:5.2f} | compile ~{cold - warm:5.1f} s | "
        f"{variants:3d} variants | target cold <= {limit:.1f} s: {'met' if cold <= limit else 'NOT met'}"
    )
    return {"cold": cold, "warm": warm, "ratio": cold / warm}


KERNELS = """
import sys, time
from collections import defaultdict
from numba.core import event
from mocapflow.framework.cli import main

own, stack = defaultdict(float), []

class Timer(event.Listener):
    def on_start(self, ev):
        stack.append([ev.data["dispatcher"].py_func.__qualname__, time.perf_counter(), 0.0])
    def on_end(self, ev):
        name, t0, inner = stack.pop()
        took = time.perf_counter() - t0
        own[name] += took - inner  # exclusive: kernels it compiled on the way are their own rows
        if stack:
            stack[-1][2] += took

event.register("numba:compile", Timer())
code = main(sys.argv[1:])
for name, t in sorted(own.items(), key=lambda kv: -kv[1]):
    print(f"KERNEL {t:.3f} {name}")
sys.exit(code)
"""


def kernels(case: str) -> None:
    """Compile seconds per kernel (exclusive of the kernels it calls) in a cold run."""
    with tempfile.TemporaryDirectory(prefix="mocapflow-first-run-") as tmp_s:
        tmp = Path(tmp_s)
        cold_cmd, _ = _case_commands(case, tmp)
        env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp / "numba-cache"), "MOCAPFLOW_PROGRESS": "0"}
        res = subprocess.run(
            [sys.executable, "-c", KERNELS, *cold_cmd[3:]], capture_output=True, text=True, env=env, cwd=tmp
        )
    rows = [line.split(" ", 2)[1:] for line in res.stdout.splitlines() if line.startswith("KERNEL ")]
    total = sum(float(t) for t, _ in rows)
    print(f"  {case}: {len(rows)} kernels compiled in this process, {total:.1f} s (workers not seen)")
    for t, name in rows[:20]:
        print(f"    {float(t):6.2f} s  {name}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a one-clip pipeline, once")
    ap.add_argument("--repeat", type=int, default=None, help="repetitions (default 3; --quick: 1)")
    ap.add_argument("--only", choices=("quickstart", "clean", "tiny"), action="append", help="cases to run")
    ap.add_argument("--kernels", action="store_true", help="compile seconds per kernel in a cold run, no timing")
    args = ap.parse_args(argv)
    cases = args.only or (["tiny"] if args.quick else ["quickstart", "clean"])
    repeat = args.repeat or (1 if args.quick else 3)
    print(
        f"first run (empty numba cache) vs warm, {repeat} repetition(s), {os.cpu_count()} cores, "
        f"load average {os.getloadavg()[0]:.1f}"
    )
    for case in cases:
        kernels(case) if args.kernels else measure(case, repeat)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
