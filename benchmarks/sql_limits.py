"""``mocapflow sql`` limits: what the query process costs, and that the limits hold.

1. Overhead: a small query (``SELECT * FROM summary``) through :func:`limited_query` (a
   forked child with an address-space cap and a kill past ``--timeout``) against the same
   query on an open :class:`Catalog` in this process, and both with the catalog opened each
   time (what one ``mocapflow sql`` command does); medians of ``--repeat`` runs and their
   ratio, measured in the same run.
2. Hostile queries with ``--timeout 10 --memory-limit 500MB``, each as a fresh
   ``mocapflow sql`` process under ``/usr/bin/time -v``: wall seconds, peak RSS (the largest
   process of the tree), exit status and the limit the message names. Target: every query
   ended within timeout + 5 s at a peak <= limit + 500 MB.

    python benchmarks/sql_limits.py --quick     # 5 repetitions
    python benchmarks/sql_limits.py             # 30 repetitions
"""

from __future__ import annotations

import argparse
import re
import statistics
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HOSTILE = [
    "SELECT length(repeat('x', 2000000000))",
    "SELECT list(repeat('x', 1000)) FROM range(10000000)",
    "SELECT repeat('x', 100000000) AS s FROM range(100)",
    "SELECT count(*) FROM range(10000000000000)",
    "SELECT max(a.range * b.range) FROM range(100000000) a, range(1000) b",
]


def build_workspace(folder: Path) -> Path:
    from mocapflow.framework.runner import run_pipeline

    pipe = folder / "p.yaml"
    pipe.write_text(
        textwrap.dedent(f"""
        name: sqlbench
        workspace: ws
        steps:
          motions: {{uses: formats.load, with: {{paths: ["{ROOT}/examples/data/cmu/**/*.amc"], fps: 30}}}}
          summary: {{uses: analyses.clip_summary, input: motions}}
        """)
    )
    run_pipeline(pipe)
    return folder / "ws"


def median_s(fn, repeat: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--workspace", type=Path, help="a finished workspace with a summary step (default: built here)")
    args = ap.parse_args()
    repeat = 5 if args.quick else 30
    from mocapflow.framework.catalog import Catalog, limited_query

    with tempfile.TemporaryDirectory() as tmp:
        ws = args.workspace or build_workspace(Path(tmp))
        sql = "SELECT * FROM summary"
        with Catalog(ws, timeout=300, memory_limit="4GB") as cat:
            warm_in = median_s(lambda: cat.query(sql), repeat)
        cold_in = median_s(lambda: Catalog(ws, timeout=300, memory_limit="4GB").query(sql), repeat)
        child = median_s(lambda: limited_query(ws, sql, timeout=300, memory_limit="4GB"), repeat)
        print(f"small query ({repeat} runs, median): in-process on an open catalog {warm_in * 1e3:.1f} ms")
        print(f"  in-process, catalog opened each time (the old command) {cold_in * 1e3:.1f} ms")
        print(
            f"  limited_query (child process)                       {child * 1e3:.1f} ms "
            f"= {child / cold_in:.2f}x the old command, +{(child - cold_in) * 1e3:.1f} ms"
        )
        print("\nhostile queries, --timeout 10 --memory-limit 500MB (target: <= 15 s, peak <= 1000 MB)")
        for q in HOSTILE:
            cmd = ["/usr/bin/time", "-v", sys.executable, "-m", "mocapflow", "sql", str(ws), q]
            cmd += ["--timeout", "10", "--memory-limit", "500MB"]
            t = time.perf_counter()
            r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
            wall = time.perf_counter() - t
            rss = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", r.stderr).group(1)) / 1024
            msg = next((ln for ln in r.stderr.splitlines() if "error" in ln), "").strip()
            limit = "timeout" if "longer than" in msg else "memory" if "memory" in msg else "?"
            ok = wall <= 15 and rss <= 1000
            print(f"  {wall:5.1f} s {rss:6.0f} MB exit {r.returncode} [{limit}] {'ok' if ok else 'MISSED'}  {q[:60]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
