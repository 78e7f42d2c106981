"""First-run time of the quickstart with cold caches, and what numba compiles for it.

A new user's first ``mocapflow run pipelines/quickstart.yaml`` compiles every numba kernel
the run uses (``cache=True`` keeps them for later runs). This script runs the quickstart in a
fresh workspace with an empty numba cache (``NUMBA_CACHE_DIR`` = a new folder), then again
with ``--force`` on the now warm cache, and prints per step: cold seconds, warm seconds and
their difference (≈ compilation). It counts the compiled kernels in the cache: functions
(``.nbi`` index files) and variants (``.nbc`` files, one per signature); a function with
several variants was compiled more than once (different dtypes, layouts or argument types).

    python benchmarks/first_run.py                    # cold + warm quickstart
    python benchmarks/first_run.py --quick            # the quickstart's first steps only
    python benchmarks/first_run.py --baseline HEAD~3  # the same, also for a git revision, same run
    python benchmarks/first_run.py --steps nearest search   # these steps and their inputs only

``--baseline REV`` exports that revision (``git archive``) to a temporary folder and runs the
same measurement with it importable as ``mocapflow`` (ratios of this tree vs REV, same run,
same machine load). Target (issue 11): a cold quickstart ≤ 45 s on an idle 2-core machine.
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
QUICK_STEPS = ("motions", "summary", "fe15", "tree", "nearest")
_STEP = re.compile(r"^\s+(\S+)\s+\S+\s+computed in ([0-9.]+) s")


def _source_tree(rev: str, into: Path) -> Path:
    """``rev`` of this repository, importable as ``mocapflow`` from ``into`` (a PYTHONPATH entry)."""
    src = into / "src"
    src.mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev], capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(src)], input=archive, check=True)
    pkg = into / "path" / "mocapflow"
    pkg.mkdir(parents=True)
    top = src / "_mocapflow" / "__init__.py"
    (pkg / "__init__.py").write_text(top.read_text() if top.is_file() else '__version__ = "0"\n')
    for name in ("framework", "plugins", "pipelines"):
        (pkg / name).symlink_to(src / name)
    return into / "path"


def _with_inputs(steps: dict, wanted) -> set[str]:
    """``wanted`` and every step they read from, transitively."""
    keep, todo = set(), list(wanted)
    while todo:
        name = todo.pop()
        if name in keep:
            continue
        if name not in steps:
            raise SystemExit(f"no step {name!r} in the quickstart: {', '.join(steps)}")
        keep.add(name)
        step = steps[name]
        todo += [step["input"]] if "input" in step else list((step.get("inputs") or {}).values())
    return keep


def _pipeline(src_root: Path, steps: tuple[str, ...] | None, tmp: Path) -> Path:
    """The quickstart (or some of its steps and their inputs), with the workspace in ``tmp``."""
    import yaml

    spec = yaml.safe_load((src_root / "pipelines" / "quickstart.yaml").read_text())
    if steps:
        keep = _with_inputs(spec["steps"], steps)
        spec["steps"] = {k: v for k, v in spec["steps"].items() if k in keep}
    spec["workspace"] = str(tmp / "ws")
    for step in spec["steps"].values():  # paths are relative to the pipeline's folder
        paths = (step.get("with") or {}).get("paths")
        if paths:
            step["with"]["paths"] = [str((src_root / "pipelines" / p).resolve()) if not os.path.isabs(p) else p for p in paths]
    out = tmp / "quickstart.yaml"
    out.write_text(yaml.safe_dump(spec, sort_keys=False))
    return out


def _run(pipeline: Path, cache: Path, pythonpath: Path | None, force: bool) -> tuple[float, dict[str, float], str]:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "MOCAPFLOW_PROGRESS": "0"}
    if pythonpath is not None:
        env["PYTHONPATH"] = str(pythonpath)
    cmd = [sys.executable, "-c", "import sys; from mocapflow.framework.cli import main; sys.exit(main())",
           "--no-entry-points", "run", str(pipeline)] + (["--force"] if force else [])
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=str(pipeline.parent))
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        raise SystemExit(f"run failed ({res.returncode}):\n{res.stdout[-2000:]}\n{res.stderr[-2000:]}")
    steps = {m.group(1): float(m.group(2)) for m in map(_STEP.match, res.stdout.splitlines()) if m}
    return wall, steps, res.stdout


def _cache_counts(cache: Path) -> tuple[int, int, list[tuple[str, int]]]:
    """(functions, variants, functions with more than one variant) in a numba cache folder."""
    nbi = list(cache.rglob("*.nbi"))
    per_fn = Counter(re.sub(r"\.\d+\.nbc$", "", p.name) for p in cache.rglob("*.nbc"))
    dup = sorted(((fn, n) for fn, n in per_fn.items() if n > 1), key=lambda x: -x[1])
    return len(nbi), sum(per_fn.values()), dup


def measure(label: str, src_root: Path, pythonpath: Path | None, steps: tuple[str, ...] | None) -> dict:
    with tempfile.TemporaryDirectory(prefix="mocapflow-first-run-") as tmp_s:
        tmp = Path(tmp_s)
        pipeline = _pipeline(src_root, steps, tmp)
        cache = tmp / "numba-cache"
        cold_wall, cold, out = _run(pipeline, cache, pythonpath, force=False)
        warm_wall, warm, _ = _run(pipeline, cache, pythonpath, force=True)
        n_fn, n_var, dup = _cache_counts(cache)
    announced = "compiling numba kernels" in out
    print(f"\n{label}: cold {cold_wall:.1f} s, warm {warm_wall:.1f} s wall "
          f"(compilation ≈ {cold_wall - warm_wall:.1f} s); {n_fn} kernels, {n_var} compiled variants"
          f"{'; the first run said it was compiling' if announced else ''}")
    print(f"  {'step':<14} {'cold s':>8} {'warm s':>8} {'cold-warm':>10}")
    for step, c in cold.items():
        w = warm.get(step, float("nan"))
        print(f"  {step:<14} {c:8.2f} {w:8.2f} {c - w:10.2f}")
    if dup:
        print("  kernels compiled more than once: " + ", ".join(f"{fn} x{n}" for fn, n in dup[:12]))
    return {"cold": cold_wall, "warm": warm_wall, "variants": n_var, "functions": n_fn}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help=f"only the steps {', '.join(QUICK_STEPS)}")
    ap.add_argument("--steps", nargs="+", metavar="STEP", help="only these quickstart steps (and their inputs)")
    ap.add_argument("--baseline", metavar="REV", help="also measure this git revision, in the same run")
    args = ap.parse_args(argv)
    steps = tuple(args.steps) if args.steps else (QUICK_STEPS if args.quick else None)
    print(f"quickstart{' (' + ', '.join(steps) + ' and their inputs)' if steps else ''}, cold numba cache, "
          f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}")
    results = {}
    if args.baseline:
        with tempfile.TemporaryDirectory(prefix="mocapflow-baseline-") as base_s:
            path = _source_tree(args.baseline, Path(base_s))
            results["baseline"] = measure(f"baseline {args.baseline}", Path(base_s) / "src", path, steps)
    results["this tree"] = measure("this tree", ROOT, None, steps)
    if "baseline" in results:
        b, t = results["baseline"], results["this tree"]
        print(f"\nthis tree vs {args.baseline}: cold first run {b['cold'] / t['cold']:.2f}x faster "
              f"({b['cold']:.1f} s -> {t['cold']:.1f} s), compiled variants {b['variants']} -> {t['variants']}")
    print(f"\ntarget: cold first run <= 45 s on an idle 2-core machine (this run: {results['this tree']['cold']:.1f} s, "
          f"load average {os.getloadavg()[0]:.1f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
