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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 repetitions instead of 7")
    ap.add_argument("--repeat", type=int, default=None)
    ap.add_argument("--baseline", metavar="REV", help="also time `mocapflow --help` of this git revision")
    args = ap.parse_args(argv)
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
        if args.baseline:
            sys.path.insert(0, str(Path(__file__).resolve().parent))
            from first_run import _source_tree

            path = _source_tree(args.baseline, Path(tmp) / "baseline")
            times[f"mocapflow --help at {args.baseline}"] = _time([py, "-c", CLI, "--help"], repeat, str(path))
    bare, numpy_t = times['python -c "pass"'], times['python -c "import numpy"']
    print(f"warm start-up, median of {repeat}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}")
    print(f"  {'command':<34} {'seconds':>8} {'vs numpy':>9} {'vs pass':>8}  target < 0.5 s")
    for name, t in times.items():
        target = "" if not name.startswith("mocapflow") or name.endswith(("plugins", "yaml")) else ("ok" if t < 0.5 else "SLOW")
        print(f"  {name:<34} {t:8.3f} {t / numpy_t:8.2f}x {t / bare:7.2f}x  {target}")
    print("(`plugins` and `plan` build every registry, i.e. import every plugin: not start-up)")
    if args.baseline:
        before = times[f"mocapflow --help at {args.baseline}"]
        print(f"mocapflow --help: {before:.3f} s at {args.baseline} -> {times['mocapflow --help']:.3f} s "
              f"({before / times['mocapflow --help']:.1f}x faster)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
