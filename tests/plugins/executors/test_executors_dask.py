"""``executor: dask`` on LocalClusters of worker processes on loopback (started by the tests)."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import numpy as np
import pytest

distributed = pytest.importorskip(
    "distributed", reason="the dask extra is not installed (pip install 'mocapflow[dask]')"
)

from test_executors import table_bytes, workspace_tables  # noqa: E402 - after pytest.importorskip: skip cleanly without the optional extra

from mocapflow.framework import FeatureSet, Params, PipelineError, get_plugin_manager, hookimpl  # noqa: E402 - after pytest.importorskip: skip cleanly without the optional extra
from mocapflow.framework.runner import run_pipeline  # noqa: E402 - after pytest.importorskip: skip cleanly without the optional extra
from mocapflow.plugins.executors.dask_cluster import DaskExecutor  # noqa: E402 - after pytest.importorskip: skip cleanly without the optional extra

REPO = Path(__file__).resolve().parents[3]
CMU = REPO / "examples" / "data" / "cmu"

PIPELINE = f"""
name: d
workspace: ws
steps:
  motions: {{uses: formats.load, with: {{paths: ["{CMU}/**/*.amc"], fps: 12}}}}
  fe15: {{uses: features.end_effectors, input: motions}}
  relational: {{uses: features.relational, input: motions}}
  shards: {{uses: indexes.sharded, input: fe15, with: {{shards: 2}}}}
  near: {{uses: analyses.nearest_poses, inputs: {{index: shards, motions: motions}}, with: {{queries: ["02_01:30"], k: 8}}}}
  clean: {{uses: cleaners.mdm, inputs: {{motions: motions, context: motions}}, with: {{heatmaps: false}}}}
"""


@pytest.fixture(scope="module")
def cluster():
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address="127.0.0.1:0"
    ) as c:
        yield c


def _square(x):
    return x * x


def test_the_dask_executor_is_registered_and_maps_in_order(cluster, monkeypatch):
    from mocapflow.framework.plugins import build_registries
    from mocapflow.framework.runner import make_executor

    monkeypatch.setenv("MOCAPFLOW_DASK_ADDRESS", cluster.scheduler_address)
    ex = make_executor(build_registries(get_plugin_manager(entry_points=False)), "dask", jobs=1)
    try:
        assert ex.workers == 2
        assert ex.map(_square, list(range(20)), desc="squares") == [x * x for x in range(20)]
    finally:
        ex.close()
    assert cluster.scheduler_info["workers"]  # closing the executor leaves a cluster it did not start


def test_batches_go_out_in_chunks_and_come_back_in_order(cluster):
    for per_worker, n in ((0, 7), (1, 7), (3, 1), (4, 20), (16, 5)):
        ex = DaskExecutor(address=cluster.scheduler_address, chunks_per_worker=per_worker)
        try:
            assert ex.map(_square, list(range(n))) == [x * x for x in range(n)], (per_worker, n)
        finally:
            ex.close()


def test_start_connects_in_the_background_and_map_waits_for_it(cluster):
    ex = DaskExecutor(address=cluster.scheduler_address)
    try:
        ex.start()  # returns at once; the runner plans meanwhile
        ex.start()  # idempotent
        assert ex.map(_square, list(range(9))) == [x * x for x in range(9)]
    finally:
        ex.close()


def test_a_failed_background_start_is_raised_by_the_first_map(monkeypatch):
    from mocapflow.framework.errors import ConfigError

    def unreachable(self):
        raise ConfigError("executor dask: cannot reach the scheduler at tcp://nowhere:8786")

    monkeypatch.setattr(DaskExecutor, "_connect", unreachable)
    ex = DaskExecutor(address="tcp://nowhere:8786")
    ex.start()
    try:
        with pytest.raises(ConfigError, match="cannot reach the scheduler"):
            ex.map(_square, [1, 2])
    finally:
        ex.close()  # nothing to close, no error


def _worker_threads(_):
    import numba

    return numba.get_num_threads(), os.environ.get("OMP_NUM_THREADS")


def test_tasks_run_with_their_share_of_the_cores(cluster):
    ex = DaskExecutor(address=cluster.scheduler_address, threads=1)
    try:
        assert all(t == (1, "1") for t in ex.map(_worker_threads, range(6)))
    finally:
        ex.close()


def test_dask_run_writes_the_same_tables_as_local(tmp_path, cluster):
    out = {}
    for name, opts in (("local", {"jobs": 1}), ("dask", {})):
        d = tmp_path / name
        d.mkdir()
        (d / "p.yaml").write_text(PIPELINE)
        ex = DaskExecutor(address=cluster.scheduler_address) if name == "dask" else None
        try:
            run_pipeline(d / "p.yaml", pm=get_plugin_manager(entry_points=False), executor=ex, **opts)
        finally:
            if ex is not None:
                ex.close()
        ws = d / "ws"
        out[name] = (
            workspace_tables(ws),
            {p.name: p.read_bytes() for p in sorted((ws / "clean").glob("*.bvh"))},
            {str(p.relative_to(ws)): p.read_bytes() for p in sorted((ws / "shards" / "index").rglob("*.npy"))},
        )
    assert out["local"][0].keys() == out["dask"][0].keys() and len(out["local"][0]) >= 8
    for name in out["local"][0]:
        assert out["local"][0][name] == out["dask"][0][name], name
    assert out["local"][1] and out["local"][1] == out["dask"][1]
    assert out["local"][2] and out["local"][2] == out["dask"][2]


class KillOnce(FeatureSet):
    """Kills the worker process running it once per ``marker`` file; the retry computes."""

    name = "kill_once"

    class Params(Params):
        marker: str = ""
        always: bool = False

    @property
    def dim(self) -> int:
        return 3

    def transform_motion(self, motion):
        m = Path(self.params.marker)
        if self.params.always or not m.exists():
            m.write_text(str(os.getpid()))
            os.kill(os.getpid(), signal.SIGKILL)
        return np.asarray(motion.root_translation, np.float32)


class KillPlugin:
    @hookimpl
    def register_features(self):
        return [KillOnce]


def _kill_pipeline(tmp_path: Path, always: bool) -> Path:
    p = tmp_path / "k.yaml"
    p.write_text(f"""
name: k
workspace: ws
steps:
  motions: {{uses: formats.load, with: {{paths: ["{CMU}/**/*.amc"], fps: 10}}}}
  feats: {{uses: features.kill_once, input: motions, with: {{marker: "{tmp_path / "killed"}", always: {str(always).lower()}}}}}
""")
    return p


def test_a_worker_killed_mid_step_is_retried_and_the_output_is_complete(tmp_path):
    p = _kill_pipeline(tmp_path, always=False)
    ex = DaskExecutor(jobs=2)
    try:
        run_pipeline(p, pm=get_plugin_manager(entry_points=False, extra=[KillPlugin()]), executor=ex)
    finally:
        ex.close()
    assert (tmp_path / "killed").is_file()  # a worker did die mid-step
    got = table_bytes(tmp_path / "ws" / "feats" / "data.parquet")
    (tmp_path / "again").mkdir()
    (tmp_path / "again" / "killed").write_text("no kill this time")
    run_pipeline(
        _kill_pipeline(tmp_path / "again", always=False),
        pm=get_plugin_manager(entry_points=False, extra=[KillPlugin()]),
        jobs=1,
    )
    assert table_bytes(tmp_path / "again" / "ws" / "feats" / "data.parquet") == got


def test_workers_that_keep_dying_end_in_a_clear_error_and_no_dataset(tmp_path):
    p = _kill_pipeline(tmp_path, always=True)
    ex = DaskExecutor(jobs=2, allowed_failures=1)
    try:
        with pytest.raises(PipelineError, match="step 'feats'.*workers running a task .* died"):
            run_pipeline(p, pm=get_plugin_manager(entry_points=False, extra=[KillPlugin()]), executor=ex)
    finally:
        ex.close()
    ws = tmp_path / "ws"
    assert (ws / "motions" / "_manifest.json").is_file()
    assert not (ws / "feats").exists()
    assert not any((ws / ".tmp").iterdir()) if (ws / ".tmp").exists() else True
