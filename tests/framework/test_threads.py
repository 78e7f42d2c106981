"""BLAS sized for the workers before NumPy loads (docs/scale-out.md):
when a run forks local workers, the client sets the BLAS thread variables before anything
imports NumPy, so that OpenBLAS loads at a worker's share of the cores instead of being
limited at run time in every forked worker (which measured slower)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from mocapflow.framework.threads import BLAS_ENV, size_blas_for_workers, workers_on_this_host

PROBE = """
import json, os, sys
from mocapflow.framework.threads import size_blas_for_workers
done = size_blas_for_workers({jobs}, cores=2)
import numpy, threadpoolctl
blas = [p["num_threads"] for p in threadpoolctl.threadpool_info() if p["user_api"] == "blas"]
print(json.dumps({{"done": done, "env": os.environ.get("OPENBLAS_NUM_THREADS"), "blas": blas}}))
"""


def _probe(jobs: int, **env: str) -> dict:
    clean = {k: v for k, v in os.environ.items() if k not in BLAS_ENV}
    r = subprocess.run(
        [sys.executable, "-c", PROBE.format(jobs=jobs)],
        capture_output=True,
        text=True,
        env={**clean, **env},
        check=True,
    )
    return json.loads(r.stdout.strip().splitlines()[-1])


def test_blas_loads_at_a_workers_share_when_the_run_forks_workers():
    out = _probe(2)
    assert out["done"] and out["env"] == "1"
    assert out["blas"] and all(n == 1 for n in out["blas"])


def test_one_process_runs_and_user_settings_keep_their_blas():
    one = _probe(1)
    assert not one["done"] and one["env"] is None
    mine = _probe(2, OPENBLAS_NUM_THREADS="2")
    assert not mine["done"] and mine["env"] == "2"


def test_too_late_once_numpy_is_loaded():
    import numpy  # noqa: F401 - loaded in this (test) process: the variables would no longer count

    before = {v: os.environ.get(v) for v in BLAS_ENV}
    assert size_blas_for_workers(2) is False
    assert {v: os.environ.get(v) for v in BLAS_ENV} == before


@pytest.mark.parametrize(
    "yaml, jobs, want",
    [
        ("executor: local\njobs: 2\n", None, 2),
        ("jobs: 3\n", None, 3),
        ("jobs: 3\n", 1, 1),  # --jobs wins
        ("{}\n", 2, 2),
        ("executor: dask\njobs: 2\n", None, 2),  # a LocalCluster beside the client
        ("executor: dask\nexecutor_options: {address: 'tcp://10.0.0.5:8786'}\njobs: 2\n", None, 1),  # remote
        ("executor: other\njobs: 2\n", None, 1),
        ("jobs: [not, a, number]\n", None, 1),
        (": not yaml: [\n", 2, 1),
    ],
)
def test_the_cli_reads_the_workers_of_a_run_without_numpy(tmp_path: Path, yaml: str, jobs, want: int):
    p = tmp_path / "p.yaml"
    p.write_text(yaml)
    assert workers_on_this_host(str(p), jobs) == want


def test_a_missing_pipeline_file_is_left_to_the_runner(tmp_path: Path):
    assert workers_on_this_host(str(tmp_path / "none.yaml"), 2) == 1


def _exit_state(call: str) -> str:
    script = (
        "import atexit, gc, sys\n"
        "atexit.register(lambda: print('frozen', gc.get_freeze_count() > 0, flush=True))\n"
        "from mocapflow.framework import cli\n"
        "sys.argv = ['mocapflow', '--version']\n"
        "try:\n"
        f"    {call}\n"
        "except SystemExit as exc:\n"
        "    print('rc', exc.code, flush=True)\n"
    )
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True).stdout


def test_the_cli_skips_the_last_collection_at_exit():
    """The console script's final garbage collection of a run's objects is skipped (gc.freeze
    at exit, after the other exit handlers): the run's outputs are closed before."""
    out = _exit_state("cli.main()")
    assert "rc 0" in out
    assert "frozen True" in out


def test_main_called_from_python_leaves_the_callers_exit_alone():
    out = _exit_state("cli.main(['--version'])")
    assert "rc 0" in out
    assert "frozen False" in out


COMPILE_AFTER_LIMIT = """
import numba, numpy as np
from mocapflow.framework.threads import _client_threads, limit_threads

@numba.njit(parallel=True, cache=False)
def total(x):
    s = 0.0
    for i in numba.prange(len(x)):
        s += x[i]
    return s

def compile_and_run():
    @numba.njit(cache=False)
    def plus_one(x):
        return x + 1

    print(plus_one(1), numba.get_num_threads())

total(np.ones(64))  # numba's pool now runs, sized at import
"""


@pytest.mark.parametrize(
    "limited",
    [
        "limit_threads(1)\ncompile_and_run()",  # a worker's share, as each worker takes first
        "with _client_threads(1):\n    compile_and_run()",  # the client's share while it works chunks
    ],
    ids=["limit_threads", "client_threads"],
)
def test_a_kernel_compiles_after_the_threads_are_limited_on_a_running_pool(limited):
    """numba re-reads NUMBA_NUM_THREADS at every compile and raises once its threads run with
    another count: a cold cache compiling a kernel after the threads were limited (a worker, or
    the client working chunks) crashed a jobs=2 run."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_NUM_THREADS"}
    r = subprocess.run([sys.executable, "-c", COMPILE_AFTER_LIMIT + limited], capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.split() == ["2", "1"]
