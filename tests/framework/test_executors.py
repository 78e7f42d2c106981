"""The local executor: thread limits in workers, fork safety, clips by reference, dying workers,
the client as worker 0 (errors, interrupts, order)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from functools import partial
from itertools import pairwise
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from mocapflow.framework import FeatureSet, Params, PipelineError, get_plugin_manager, hookimpl
from mocapflow.framework.clip_refs import clip_slices
from mocapflow.framework.context import map_clips
from mocapflow.framework.datasets import Dataset
from mocapflow.framework.executors import LocalExecutor
from mocapflow.framework.runner import run_pipeline
from mocapflow.framework.threads import threads_per_worker

REPO = Path(__file__).resolve().parents[2]
CMU = REPO / "examples" / "data" / "cmu"


def table_bytes(path: Path) -> bytes:
    """A Parquet table's content as Arrow IPC bytes, provenance metadata (times) left out."""
    t = pq.read_table(path)
    t = t.replace_schema_metadata(None)
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, t.schema) as w:
        w.write_table(t.combine_chunks())
    return sink.getvalue().to_pybytes()


def workspace_tables(ws: Path) -> dict[str, bytes]:
    return {str(p.relative_to(ws)): table_bytes(p) for p in sorted(ws.glob("*/*.parquet"))}


def _worker_threads(_):
    import numba
    from threadpoolctl import threadpool_info

    return numba.get_num_threads(), [p["num_threads"] for p in threadpool_info()], os.environ["OMP_NUM_THREADS"]


def test_threads_per_worker_never_oversubscribe():
    for cores in (1, 2, 3, 8, 16):
        for workers in (1, 2, 3, 8, 32):
            t = threads_per_worker(workers, cores)
            assert t >= 1 and (workers * t <= cores or t == 1)


@pytest.mark.parametrize("client_works", [True, False])
def test_workers_get_their_share_of_the_cores(client_works):
    """Before: every worker ran numba and OpenBLAS as wide as the machine (2 x 2 on 2 cores).
    The client, while it works as worker 0, uses a worker's share too."""
    ex = LocalExecutor(2, min_items_for_pool=1, threads=1, client_works=client_works)
    try:
        out = ex.map(_worker_threads, range(16))
    finally:
        ex.close()
    for numba_threads, blas_threads, omp in out:
        assert numba_threads == 1 and omp == "1"
        assert all(n == 1 for n in blas_threads)


FORK_SCRIPT = """
import sys
import numpy as np
from numba import njit, prange
from mocapflow.framework.executors import LocalExecutor


@njit(parallel=True)
def total(x):
    s = 0.0
    for i in prange(x.shape[0]):
        s += x[i]
    return s


def work(n):
    return total(np.ones(n))


if __name__ == "__main__":
    assert total(np.ones(1000)) == 1000.0  # the parent launches numba's OpenMP pool
    ex = LocalExecutor(2, min_items_for_pool=1, start_method=sys.argv[1] if len(sys.argv) > 1 else None)
    try:
        print(ex.map(work, [10, 20, 30, 40]))
    finally:
        ex.close()
"""


def test_pool_after_a_parallel_kernel_in_the_parent_works(tmp_path):
    """Bug: once the parent had run a parallel numba kernel (GNU OpenMP), workers forked from
    it aborted at their first parallel kernel ("fork() called from a process already using
    GNU OpenMP") -> BrokenProcessPool. Now the pool starts from a forkserver then. In a
    fresh interpreter, so that this process's OpenMP state stays as it is."""
    script = tmp_path / "fork_after_openmp.py"
    script.write_text(FORK_SCRIPT)
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "[10.0, 20.0, 30.0, 40.0]" in r.stdout
    forced = subprocess.run([sys.executable, str(script), "fork"], capture_output=True, text=True, timeout=300)
    if "GNU OpenMP" in forced.stderr or "died" in forced.stderr:  # the old behaviour, where the layer is omp
        assert forced.returncode != 0


def _die(parent, x):
    if os.getpid() != parent:  # only a pool process: the client works through chunks too
        os.kill(os.getpid(), signal.SIGKILL)
    return x


@pytest.mark.parametrize("client_works", [True, False])
def test_a_killed_worker_is_a_clear_error_and_the_pool_recovers(client_works):
    ex = LocalExecutor(2, min_items_for_pool=1, client_works=client_works)
    try:
        with pytest.raises(PipelineError, match="worker process of the local executor died"):
            ex.map(partial(_die, os.getpid()), range(8), desc="dying")
        assert ex.map(abs, [-1, -2, -3, -4]) == [1, 2, 3, 4]
    finally:
        ex.close()


# --- the client as worker 0 ------------------------------------------------------------------


def _where(parent, x):
    time.sleep(0.02)  # long enough that the pool process takes its share
    return x, os.getpid() == parent


def test_the_client_and_the_pool_share_a_batch_in_order():
    ex = LocalExecutor(2, min_items_for_pool=1, client_works=True)
    try:
        out = ex.map(partial(_where, os.getpid()), range(40))
    finally:
        ex.close()
    assert ex.processes == 1
    assert [x for x, _ in out] == list(range(40))
    assert {by_client for _, by_client in out} == {True, False}  # each chunk ran once, on one side
    assert ex.batches[-1]["client_s"] > 0 and len(ex.batches[-1]["workers_s"]) == 1


def _fail(x):
    time.sleep(0.01)
    if x in (13, 17, 30):
        raise ValueError(f"item {x}")
    return x


@pytest.mark.parametrize("jobs, client_works", [(1, True), (2, True), (2, False), (3, True)])
def test_a_failing_batch_raises_its_first_failing_item_wherever_it_ran(jobs, client_works):
    """The client's own chunks fail like a worker's: the error of the first failing item in
    input order, as in-process, and the pool stays usable."""
    ex = LocalExecutor(jobs, min_items_for_pool=1, client_works=client_works)
    try:
        with pytest.raises(ValueError, match="^item 13$"):
            ex.map(_fail, range(40))
        assert ex.map(_fail, range(8)) == list(range(8))
    finally:
        ex.close()


def _interrupt(parent, x):
    if os.getpid() == parent:
        raise KeyboardInterrupt
    time.sleep(0.02)
    return x


def test_an_interrupt_in_the_clients_chunk_is_clean():
    import numba

    before = numba.get_num_threads(), os.environ.get("OMP_NUM_THREADS")
    ex = LocalExecutor(2, min_items_for_pool=1, threads=1, client_works=True)
    try:
        with pytest.raises(KeyboardInterrupt):
            ex.map(partial(_interrupt, os.getpid()), range(16))
        assert ex.map(abs, [-1, -2, -3, -4]) == [1, 2, 3, 4]  # the pool survives
    finally:
        ex.close()
    assert (numba.get_num_threads(), os.environ.get("OMP_NUM_THREADS")) == before  # the client's threads restored


# --- clips by reference ------------------------------------------------------------------


def _motions_workspace(tmp_path: Path, monkeypatch, rows_per_group: int = 24) -> Dataset:
    """A motions dataset of the bundled CMU takes written with small row groups."""
    import mocapflow.framework.workspace as workspace

    monkeypatch.setattr(workspace, "ROW_GROUP_ROWS", rows_per_group)
    p = tmp_path / "m.yaml"
    p.write_text(
        f"name: m\nworkspace: ws\nsteps:\n  motions: {{uses: formats.load, with: {{paths: ['{CMU}/**/*.amc'], fps: 10}}}}\n"
    )
    run_pipeline(p, pm=get_plugin_manager(entry_points=False))
    return Dataset(tmp_path / "ws" / "motions")


def test_clip_slices_read_exactly_the_clips_of_the_dataset(tmp_path, monkeypatch):
    ds = _motions_workspace(tmp_path, monkeypatch)
    assert pq.ParquetFile(ds.path / "data.parquet").metadata.num_row_groups > 4
    whole = ds.motions()
    for n in (1, 3, 8, 50):
        pieces = clip_slices(ds, n)
        assert pieces[0].start == 0 and pieces[-1].stop == whole.n_clips
        assert all(a.stop == b.start for a, b in pairwise(pieces))
        got = [(int(c), m) for p in pieces for c, m in zip(p.motions().clip_ids, p.motions().motions, strict=True)]
        assert [c for c, _ in got] == whole.clip_ids.tolist()
        for (_, m), ref in zip(got, whole.motions, strict=True):
            assert m.name == ref.name and m.metadata == ref.metadata
            np.testing.assert_array_equal(m.rotations, ref.rotations)
            np.testing.assert_array_equal(m.root_translation, ref.root_translation)


def _n_frames(motion) -> int:
    return motion.n_frames


def test_map_clips_on_a_pool_equals_in_process(tmp_path, monkeypatch):
    ds = _motions_workspace(tmp_path, monkeypatch)
    ex = LocalExecutor(2)
    try:
        pooled = map_clips(ex, _n_frames, ds)
    finally:
        ex.close()
    assert pooled == map_clips(LocalExecutor(1), _n_frames, ds) == [m.n_frames for m in ds.motions().motions]


# --- whole pipelines -----------------------------------------------------------------------

PIPELINE = f"""
name: par
workspace: ws
steps:
  motions: {{uses: formats.load, with: {{paths: ["{CMU}/**/*.amc"], fps: 12}}}}
  fe15: {{uses: features.end_effectors, input: motions}}
  fe15x3: {{uses: features.end_effectors, input: motions, with: {{samples: 3}}}}
  relational: {{uses: features.relational, input: motions}}
  tree: {{uses: indexes.kdtree, input: fe15}}
  search: {{uses: matchers.search, inputs: {{database: tree, query: motions}}, with: {{count: 3, queries: ["16_15:10-40", "02_01:5-30", "02_02:0-25", "35_01:5-30", "16_01:3-33"]}}}}
  clean: {{uses: cleaners.mdm, inputs: {{motions: motions, context: motions}}, with: {{heatmaps: false}}}}
"""


def test_jobs_2_writes_the_same_tables_and_files_as_jobs_1(tmp_path):
    out = {}
    for jobs in (1, 2, "2-client", "2-prestart", "2-pool"):
        d = tmp_path / f"j{jobs}"
        d.mkdir()
        (d / "p.yaml").write_text(PIPELINE)
        # 2: the default layout; client: the client is worker 0 beside one pool process;
        # prestart: the pool forks before planning and warms itself up; pool: two pool
        # processes while the client waits
        options = {
            "2-client": {"client_works": True},
            "2-prestart": {"prestart": True},
            "2-pool": {"client_works": False},
        }.get(jobs)
        ex = LocalExecutor(2, **options) if options else None
        try:
            run_pipeline(d / "p.yaml", jobs=2 if ex else jobs, pm=get_plugin_manager(entry_points=False), executor=ex)
        finally:
            if ex is not None:
                ex.close()
        ws = d / "ws"
        out[jobs] = (workspace_tables(ws), {p.name: p.read_bytes() for p in sorted((ws / "clean").glob("*.bvh"))})
    assert out[1][0].keys() == out[2][0].keys() and len(out[1][0]) >= 8
    for other in (2, "2-client", "2-prestart", "2-pool"):
        for name in out[1][0]:
            assert out[1][0][name] == out[other][0][name], (other, name)
        assert out[1][1] and out[1][1] == out[other][1]


@pytest.mark.parametrize("client_works", [True, False])
def test_prestart_forks_every_worker_before_the_first_batch(client_works):
    ex = LocalExecutor(2, min_items_for_pool=1, threads=1, prestart=True, client_works=client_works)
    try:
        ex.start()
        # forked at start(), warming up while the client plans
        assert len(ex._pool._processes) == (1 if client_works else 2)
        out = ex.map(_worker_threads, range(4))
    finally:
        ex.close()
    assert all(t[0] == 1 and t[2] == "1" for t in out)


class KillerFeatures(FeatureSet):
    """Kills the worker process it runs in (never the test process)."""

    name = "killer"

    class Params(Params):
        parent: int = 0

    @property
    def dim(self) -> int:
        return 1

    def transform_motion(self, motion):
        if os.getpid() != self.params.parent:
            os.kill(os.getpid(), signal.SIGKILL)
        return np.zeros((motion.n_frames, 1), np.float32)


class KillerPlugin:
    @hookimpl
    def register_features(self):
        return [KillerFeatures]


def test_a_worker_killed_mid_step_leaves_no_dataset(tmp_path):
    (tmp_path / "p.yaml").write_text(f"""
name: k
workspace: ws
steps:
  motions: {{uses: formats.load, with: {{paths: ["{CMU}/**/*.amc"], fps: 10}}}}
  feats: {{uses: features.killer, input: motions, with: {{parent: {os.getpid()}}}}}
""")
    pm = get_plugin_manager(entry_points=False, extra=[KillerPlugin()])
    with pytest.raises(PipelineError, match="step 'feats'.*worker process .* died"):
        run_pipeline(tmp_path / "p.yaml", jobs=2, pm=pm)
    ws = tmp_path / "ws"
    assert (ws / "motions" / "_manifest.json").is_file()
    assert not (ws / "feats").exists()
    assert not any((ws / ".tmp").glob("*")) if (ws / ".tmp").exists() else True


def test_the_client_works_by_default_only_where_workers_pay_their_own_start_up():
    ex = LocalExecutor(2)
    assert ex._client_works("fork", warm_parent=True) is False  # forked after warm_up: inherited
    assert ex._client_works("fork", warm_parent=False) is False  # prestart: measured slower
    assert ex._client_works("spawn", warm_parent=True) is True
    assert ex._client_works("forkserver", warm_parent=True) is True
    assert LocalExecutor(2, client_works=True)._client_works("fork", True) is True


def test_workers_resolve_components_with_the_registries_of_the_run(tmp_path):
    """``--block`` holds on the workers: with the built-in similarity package blocked, the
    ``indexes.kdtree`` of the run is a stand-in, and the workers that match the queries load
    the saved index with it (registries rebuilt on a worker would bring the built-in back,
    which cannot read the stand-in's files)."""
    from toy_components import StandInPlugin, ToyPlugin

    p = tmp_path / "p.yaml"
    p.write_text(
        "name: blocked\nworkspace: ws\njobs: 2\nexecutor_options: {min_items_for_pool: 1}\nsteps:\n"
        "  motions: {uses: analyses.toy_motions, with: {clips: 4, frames: 20}}\n"
        "  feats: {uses: features.toy_root, input: motions}\n"
        "  idx: {uses: indexes.kdtree, input: feats}\n"
        "  found: {uses: matchers.toy_nearest, inputs: {database: idx, query: motions, features: feats}}\n"
    )
    blocked = ["mocapflow.plugins.similarity.plugin"]
    pm = get_plugin_manager(entry_points=False, blocked=blocked, extra=[ToyPlugin(), StandInPlugin()])
    run_pipeline(p, pm=pm)
    found = Dataset(tmp_path / "ws" / "found").table()
    # each clip's first frame is its own nearest row: distance 0 on every worker
    assert found.num_rows == 4 and found["cost"].to_pylist() == [0.0] * 4
