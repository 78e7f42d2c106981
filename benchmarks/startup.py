"""Start-up of ``mocapflow``: warm command start-up and the quickstart's cold first run.

1. Warm start-up: each command runs in a fresh process, ``--repeat`` times after one untimed
   warm-up (the OS file cache and ``__pycache__`` are warm, as for a user's second command);
   the median wall time is printed with its ratio to ``python -c "import numpy"`` and to a
   bare ``python -c pass``, measured in the same run. Target: every command < 0.5 s.
2. First run (not with ``--quick``): the quickstart in
   a fresh workspace with an empty numba cache (``NUMBA_CACHE_DIR`` = a new folder), then
   again with ``--force`` on the now warm cache; per step cold seconds, warm seconds and
   their difference (about the compilation), and the kernels in the cache: functions
   (``.nbi``) and variants (``.nbc``, one per signature). Target: a cold quickstart <= 45 s
   on an idle 2-core machine.

``--search-db WORKSPACE --query FILE[:A-B]`` also times ``mocapflow search`` on a finished workspace (target < 1 s per query
at 1 M frames): in a fresh process (``--no-server``) and through a search server
(``--serve``, started and stopped here). ``--build-db N`` first builds such a workspace from
the cached augmented corpus of ``N`` frames (benchmarks/corpus.py: motions,
``features.end_effectors``, ``indexes.kdtree``; steps that exist are reused).

    python benchmarks/startup.py --quick    # warm start-up, 2 repetitions, a few commands
    python benchmarks/startup.py            # warm start-up (7 repetitions) and the cold first run
    python benchmarks/startup.py --build-db 1038388 --search-db /tmp/ws1m \
        --query examples/data/cmu/16/16_15.amc:1s-3s
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLI = "import sys; from mocapflow.framework.cli import main; sys.exit(main())"

_STEP = re.compile(r"^\s+(\S+)\s+\S+\s+computed in ([0-9.]+) s")


def _pipeline(src_root: Path, tmp: Path) -> Path:
    """The quickstart with the workspace in ``tmp``."""
    import yaml

    spec = yaml.safe_load((src_root / "pipelines" / "quickstart.yaml").read_text())
    spec["workspace"] = str(tmp / "ws")
    for step in spec["steps"].values():  # paths are relative to the pipeline's folder
        paths = (step.get("with") or {}).get("paths")
        if paths:
            step["with"]["paths"] = [
                str((src_root / "pipelines" / p).resolve()) if not os.path.isabs(p) else p for p in paths
            ]
    out = tmp / "quickstart.yaml"
    out.write_text(yaml.safe_dump(spec, sort_keys=False))
    return out


def _run(pipeline: Path, cache: Path, force: bool) -> tuple[float, dict[str, float], str]:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "MOCAPFLOW_PROGRESS": "0"}
    cmd = [sys.executable, "-c", CLI, "--no-entry-points", "run", str(pipeline)] + (["--force"] if force else [])
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


def measure(label: str, src_root: Path) -> dict:
    with tempfile.TemporaryDirectory(prefix="mocapflow-first-run-") as tmp_s:
        tmp = Path(tmp_s)
        pipeline = _pipeline(src_root, tmp)
        cache = tmp / "numba-cache"
        cold_wall, cold, out = _run(pipeline, cache, force=False)
        warm_wall, warm, _ = _run(pipeline, cache, force=True)
        n_fn, n_var, dup = _cache_counts(cache)
    announced = "compiling numba kernels" in out
    print(
        f"\n{label}: cold {cold_wall:.1f} s, warm {warm_wall:.1f} s wall "
        f"(compilation ≈ {cold_wall - warm_wall:.1f} s); {n_fn} kernels, {n_var} compiled variants"
        f"{'; the first run said it was compiling' if announced else ''}"
    )
    print(f"  {'step':<14} {'cold s':>8} {'warm s':>8} {'cold-warm':>10}")
    for step, c in cold.items():
        w = warm.get(step, float("nan"))
        print(f"  {step:<14} {c:8.2f} {w:8.2f} {c - w:10.2f}")
    if dup:
        print("  kernels compiled more than once: " + ", ".join(f"{fn} x{n}" for fn, n in dup[:12]))
    return {"cold": cold_wall, "warm": warm_wall, "variants": n_var, "functions": n_fn}


def _time(cmd: list[str], repeat: int) -> float:
    env = {**os.environ, "MOCAPFLOW_PROGRESS": "0"}
    subprocess.run(cmd, capture_output=True, env=env)  # warm-up
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run(cmd, capture_output=True, env=env)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def build_workspace(n_frames: int, ws: Path) -> None:
    """A search workspace of the augmented corpus of ``n_frames`` frames (motions, F_E^15, kd-tree)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from corpus import augmented_database
    from pydantic import Field

    from mocapflow.framework import Format, StepOutput, get_plugin_manager, hookimpl
    from mocapflow.framework import Params as BaseParams
    from mocapflow.framework.motion_tables import motions_to_tables
    from mocapflow.framework.runner import run_pipeline

    class BenchCorpus(Format):
        """The cached augmented corpus as a motions step (benchmark only)."""

        name, is_step, output_kind = "bench_corpus", True, "motions"

        class Params(BaseParams):  # a class body does not see the function's names it rebinds
            frames: int = Field(1038388, ge=1)

        def run(self, inputs, ctx):
            ms = list(augmented_database(self.params.frames))
            return StepOutput(motions_to_tables(ms, list(range(len(ms)))), {"clips": len(ms)})

    class BenchPlugin:
        @hookimpl
        def register_formats(self):
            return [BenchCorpus]

    ws.mkdir(parents=True, exist_ok=True)
    p = ws / "bench-search.yaml"
    p.write_text(f"""name: bench-search
workspace: {ws}
steps:
  motions: {{uses: formats.bench_corpus, with: {{frames: {n_frames}}}}}
  fe15: {{uses: features.end_effectors, input: motions, with: {{joints: 5}}}}
  tree: {{uses: indexes.kdtree, input: fe15}}
""")
    run_pipeline(p, pm=get_plugin_manager(extra=[BenchPlugin()]), echo=lambda m: print(m, file=sys.stderr))


def _start_server(py: str, db: str) -> subprocess.Popen:
    env = {**os.environ, "MOCAPFLOW_PROGRESS": "0"}
    proc = subprocess.Popen(
        [py, "-c", CLI, "search", "--db", db, "--serve"],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    seen = []
    for line in proc.stderr:  # "search server on ... (warm in x s)" once it listens; notices before it
        seen.append(line)
        if "server on" in line:
            break
    else:
        proc.kill()
        raise SystemExit(f"search server did not start: {''.join(seen)}")
    print(line.strip().replace("mocapflow: ", ""))
    return proc


def warm_startup(args, repeat: int, tmp: Path) -> None:
    py = sys.executable
    missing = str(tmp / "no-workspace")
    cases = {
        'python -c "pass"': [py, "-c", "pass"],
        'python -c "import numpy"': [py, "-c", "import numpy"],
        "mocapflow --version": [py, "-c", CLI, "--version"],
        "mocapflow --help": [py, "-c", CLI, "--help"],
        "mocapflow run --help": [py, "-c", CLI, "run", "--help"],
    }
    if not args.quick:
        cases |= {
            "mocapflow search --help": [py, "-c", CLI, "search", "--help"],
            "mocapflow sql MISSING (error)": [py, "-c", CLI, "sql", missing, "SELECT 1"],
            "mocapflow plugins": [py, "-c", CLI, "plugins"],
            "mocapflow plan quickstart.yaml": [py, "-c", CLI, "plan", str(ROOT / "pipelines" / "quickstart.yaml")],
        }
    times = {name: _time(cmd, repeat) for name, cmd in cases.items()}
    if args.search_db:
        db = str(Path(args.search_db).resolve())
        cmd = [py, "-c", CLI, "search", "--db", db, "--query", args.query]
        times["mocapflow search (fresh process)"] = _time(cmd + ["--no-server"], repeat)
        server = _start_server(py, db)
        try:
            times["mocapflow search (search server)"] = _time(cmd, repeat)
        finally:
            server.terminate()
            server.wait(30)
    bare, numpy_t = times['python -c "pass"'], times['python -c "import numpy"']
    print(f"warm start-up, median of {repeat}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}")
    print(f"  {'command':<34} {'seconds':>8} {'vs numpy':>9} {'vs pass':>8}  target < 0.5 s")
    for name, t in times.items():
        limit = 1.0 if name.startswith("mocapflow search (") else 0.5
        target = (
            ""
            if not name.startswith("mocapflow") or name.endswith(("plugins", "yaml"))
            else ("ok" if t < limit else "SLOW")
        )
        print(f"  {name:<34} {t:8.3f} {t / numpy_t:8.2f}x {t / bare:7.2f}x  {target}")
    print(
        "(`plugins` and `plan` build every registry, i.e. import every plugin: not start-up; "
        "`search (...)` rows: target < 1 s per query)"
    )


def first_run() -> None:
    print(f"\nquickstart, cold numba cache, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}")
    cold = measure("this tree", ROOT)["cold"]
    print(f"target: cold first run <= 45 s on an idle 2-core machine (this run: {cold:.1f} s)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2 repetitions of a few commands, no first run")
    ap.add_argument("--repeat", type=int, default=None)
    ap.add_argument("--search-db", metavar="WORKSPACE", help="also time `mocapflow search` on this workspace")
    ap.add_argument("--query", default=str(ROOT / "examples/data/cmu/16/16_15.amc") + ":1s-3s")
    ap.add_argument("--build-db", type=int, metavar="FRAMES", help="first build --search-db from the cached corpus")
    args = ap.parse_args(argv)
    if args.build_db:
        if not args.search_db:
            ap.error("--build-db needs --search-db")
        build_workspace(args.build_db, Path(args.search_db))
    repeat = args.repeat or (2 if args.quick else 7)
    with tempfile.TemporaryDirectory() as tmp:
        warm_startup(args, repeat, Path(tmp))
        if not args.quick:
            first_run()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
