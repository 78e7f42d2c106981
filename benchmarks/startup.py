"""Warm start-up time of ``mocapflow`` commands against ``python -c "import numpy"``.

Each command runs in a fresh process, ``--repeat`` times after one untimed warm-up (the
OS file cache and ``__pycache__`` are warm, as for a user's second command); the median
wall time is printed with its ratio to ``python -c "import numpy"`` and to a bare
``python -c pass``, measured in the same run. Target (issue 13): every command < 0.5 s.

    python benchmarks/startup.py            # 7 repetitions
    python benchmarks/startup.py --quick    # 3 repetitions
    python benchmarks/startup.py --baseline HEAD~5   # also `mocapflow --help` of a git revision

``--baseline REV`` exports that revision (as ``benchmarks/first_run.py`` does) and times its
``mocapflow --help`` in the same run.

``--search-db WORKSPACE --query FILE[:A-B]`` also times ``mocapflow search`` on a finished
workspace (target: < 1 s wall per query at 1 M frames): in a fresh process (``--no-server``),
then through a search server (``--serve``, started and stopped here), and with
``--baseline`` the revision's fresh process too. ``--build-db N`` first builds such a
workspace from the cached augmented corpus of ``N`` frames (benchmarks/corpus.py; motions,
``features.end_effectors`` and ``indexes.kdtree``, steps that exist are reused):

    python benchmarks/startup.py --quick --build-db 1038388 --search-db /tmp/ws1m \
        --query examples/data/cmu/16/16_15.amc:1s-3s --baseline HEAD~1
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

ROOT = Path(__file__).resolve().parents[1]
CLI = "import sys; from mocapflow.framework.cli import main; sys.exit(main())"


def _time(cmd: list[str], repeat: int, pythonpath: str | None = None) -> float:
    env = {**os.environ, "MOCAPFLOW_PROGRESS": "0"}
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
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

    from mocapflow.framework import Format, Params, StepOutput, get_plugin_manager, hookimpl
    from mocapflow.framework.motion_tables import motions_to_tables
    from mocapflow.framework.runner import run_pipeline

    class BenchCorpus(Format):
        """The cached augmented corpus as a motions step (benchmark only)."""

        name, is_step, output_kind = "bench_corpus", True, "motions"

        class Params(Params):
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


def _search_cases(py: str, db: str, query: str, baseline: Path | None) -> dict[str, tuple]:
    cmd = [py, "-c", CLI, "search", "--db", db, "--query", query]
    cases = {"mocapflow search (fresh process)": (cmd + ["--no-server"], None)}
    if baseline is not None:
        cases["mocapflow search (fresh, baseline)"] = (cmd, str(baseline))
    return cases


def _start_server(py: str, db: str) -> subprocess.Popen:
    env = {**os.environ, "MOCAPFLOW_PROGRESS": "0"}
    proc = subprocess.Popen([py, "-c", CLI, "search", "--db", db, "--serve"], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    line = proc.stderr.readline()  # "search server on ... (warm in x s)" once it listens
    if "server on" not in line:
        proc.kill()
        raise SystemExit(f"search server did not start: {line}{proc.stderr.read()}")
    print(line.strip().replace("mocapflow: ", ""))
    return proc


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 repetitions instead of 7")
    ap.add_argument("--repeat", type=int, default=None)
    ap.add_argument("--baseline", metavar="REV", help="also time `mocapflow --help` of this git revision")
    ap.add_argument("--search-db", metavar="WORKSPACE", help="also time `mocapflow search` on this workspace")
    ap.add_argument("--query", default=str(ROOT / "examples/data/cmu/16/16_15.amc") + ":1s-3s")
    ap.add_argument("--build-db", type=int, metavar="FRAMES", help="first build --search-db from the cached corpus")
    args = ap.parse_args(argv)
    if args.build_db:
        build_workspace(args.build_db, Path(args.search_db))
    repeat = args.repeat or (3 if args.quick else 7)
    py = sys.executable
    with tempfile.TemporaryDirectory() as tmp:
        missing = str(Path(tmp) / "no-workspace")
        cases = {
            'python -c "pass"': [py, "-c", "pass"],
            'python -c "import numpy"': [py, "-c", "import numpy"],
            "mocapflow --version": [py, "-c", CLI, "--version"],
            "mocapflow --help": [py, "-c", CLI, "--help"],
            "mocapflow run --help": [py, "-c", CLI, "run", "--help"],
            "mocapflow search --help": [py, "-c", CLI, "search", "--help"],
            "mocapflow sql MISSING (error)": [py, "-c", CLI, "sql", missing, "SELECT 1"],
            "mocapflow plugins": [py, "-c", CLI, "plugins"],
            "mocapflow plan quickstart.yaml": [py, "-c", CLI, "plan", str(ROOT / "pipelines" / "quickstart.yaml")],
        }
        times = {name: _time(cmd, repeat) for name, cmd in cases.items()}
        path = None
        if args.baseline:
            sys.path.insert(0, str(Path(__file__).resolve().parent))
            from first_run import _source_tree

            path = _source_tree(args.baseline, Path(tmp) / "baseline")
            times[f"mocapflow --help at {args.baseline}"] = _time([py, "-c", CLI, "--help"], repeat, str(path))
        if args.search_db:
            db = str(Path(args.search_db).resolve())
            for name, (cmd, pp) in _search_cases(py, db, args.query, path).items():
                times[name] = _time(cmd, repeat, pp)
            server = _start_server(py, db)
            try:
                cmd = [py, "-c", CLI, "search", "--db", db, "--query", args.query]
                times["mocapflow search (search server)"] = _time(cmd, repeat)
            finally:
                server.terminate()
                server.wait(30)
    bare, numpy_t = times['python -c "pass"'], times['python -c "import numpy"']
    print(f"warm start-up, median of {repeat}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}")
    print(f"  {'command':<34} {'seconds':>8} {'vs numpy':>9} {'vs pass':>8}  target < 0.5 s")
    for name, t in times.items():
        limit = 1.0 if name.startswith("mocapflow search (") else 0.5
        target = "" if not name.startswith("mocapflow") or name.endswith(("plugins", "yaml")) else (
            "ok" if t < limit else "SLOW")
        print(f"  {name:<34} {t:8.3f} {t / numpy_t:8.2f}x {t / bare:7.2f}x  {target}")
    print("(`plugins` and `plan` build every registry, i.e. import every plugin: not start-up; "
          "`search (...)` rows: target < 1 s per query)")
    if args.baseline:
        before = times[f"mocapflow --help at {args.baseline}"]
        print(f"mocapflow --help: {before:.3f} s at {args.baseline} -> {times['mocapflow --help']:.3f} s "
              f"({before / times['mocapflow --help']:.1f}x faster)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
