"""Every benchmark the runner lists runs on its tiny input (``--quick``) and exits 0, so none rots."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"
sys.path.insert(0, str(BENCH))
from run import BENCHMARKS  # noqa: E402 - the runner's list, importable once benchmarks/ is on the path

#: Seconds per benchmark: ~30 s on two idle cores, with room for a loaded machine and a cold numba cache.
TIMEOUT = 240


def test_runner_lists_every_benchmark():
    out = subprocess.run([sys.executable, str(BENCH / "run.py"), "--list"], capture_output=True, text=True, check=True)
    assert [line.split()[0] for line in out.stdout.splitlines()] == list(BENCHMARKS)


@pytest.mark.parametrize("name", list(BENCHMARKS))
def test_benchmark_runs_quick(name, tmp_path):
    script = BENCH / f"{name}.py"
    assert script.is_file(), f"the runner lists {name} but benchmarks/{name}.py is missing"
    env = {**os.environ, "MOCAPFLOW_PROGRESS": "0", "MOCAPFLOW_BENCH_CACHE": str(tmp_path / "cache")}
    res = subprocess.run(
        [sys.executable, str(script), "--quick"], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=TIMEOUT
    )
    assert res.returncode == 0, f"{name} --quick exited {res.returncode}:\n{res.stdout[-2000:]}\n{res.stderr[-3000:]}"
