from __future__ import annotations

import json
import textwrap
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from toy_components import ToyPlugin

from mocapflow.framework import ConfigError, PipelineError, get_plugin_manager
from mocapflow.framework.plugins import build_registries
from mocapflow.framework.runner import plan_pipeline, run_pipeline


def pm():
    return get_plugin_manager(entry_points=False, extra=[ToyPlugin()])


def write(tmp_path: Path, body: str, name: str = "p.yaml") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(body))
    return p


CHAIN = """
name: chain
workspace: ws
steps:
  src: {uses: analyses.toy_source, with: {n: 4}}
  plus: {uses: analyses.toy_add, input: src, with: {add: 10}}
  other: {uses: analyses.toy_source, with: {n: 2}}
  both: {uses: analyses.toy_add, inputs: {source: plus, other: other}}
"""


def calls(ws: Path) -> list[str]:
    f = ws / "calls.log"
    return f.read_text().split() if f.exists() else []


def plan(path, overrides=()):
    return plan_pipeline(path, overrides, registries=build_registries(pm()))


@pytest.mark.parametrize(
    "body, line, words",
    [
        ("steps:\n  a: {uses: analyses.toy_sourse}\n", 2, ["did you mean 'analyses.toy_source'"]),
        ("steps:\n  a:\n    uses: analyses.toy_source\n    with: {n: 0}\n", 4, ["'n'", "greater than or equal to 1"]),
        (
            "steps:\n  a:\n    uses: analyses.toy_source\n    with:\n      sclae: 2\n",
            5,
            ["unknown parameter 'sclae'", "did you mean 'scale'"],
        ),
        ("steps:\n  a: {uses: analyses.toy_add}\n", 2, ["missing required input 'source'"]),
        (
            "steps:\n  a: {uses: analyses.toy_add, input: sorce}\n  source: {uses: analyses.toy_source}\n",
            2,
            ["unknown step 'sorce'", "did you mean 'source'"],
        ),
        ("steps:\n  a: {uses: analyses.toy_add, input: b}\n  b: {uses: analyses.toy_add, input: a}\n", 2, ["cycle"]),
        ("steps:\n  a: {uses: analyses.toy_add, inputs: {sourse: a}}\n", 2, ["no input 'sourse'"]),
        ("steps:\n  a: {uses: nothing}\n", 2, ["expected '<kind>.<name>'"]),
        ("steps:\n  a: {uses: analyses.toy_source, wiht: {}}\n", 2, ["wiht"]),
    ],
)
def test_invalid_pipelines_name_file_line_step_and_key(tmp_path, body, line, words):
    p = write(tmp_path, "name: bad\n" + body)
    with pytest.raises(ConfigError) as err:
        plan(p)
    msg = str(err.value)
    assert f"{p}:{line + 1}" in msg, msg
    for w in words:
        assert w in msg, msg


def test_yaml_syntax_error_points_at_line(tmp_path):
    p = write(tmp_path, "name: x\nsteps:\n  a: {uses: [\n")
    with pytest.raises(ConfigError, match=r"p\.yaml:\d+: invalid YAML"):
        plan(p)


def test_run_skips_unchanged_and_recomputes_exactly_downstream(tmp_path):
    p = write(tmp_path, CHAIN)
    first = run_pipeline(p, pm=pm())
    ws = tmp_path / "ws"
    assert [r.status for r in first] == ["computed"] * 4
    assert pq.read_table(ws / "both" / "data.parquet")["x"].to_pylist() == [11.0, 12.0, 13.0, 14.0]
    meta = json.loads(pq.read_schema(ws / "plus" / "data.parquet").metadata[b"mocapflow"])
    assert meta["component"] == "analyses.toy_add" and meta["params"] == {"add": 10.0}
    assert meta["inputs"]["source"]["step"] == "src"
    assert (ws / "src" / "note.txt").read_text() == "side file"
    n = len(calls(ws))
    again = run_pipeline(p, pm=pm())
    assert all(r.status == "up to date" for r in again) and len(calls(ws)) == n
    changed = run_pipeline(p, pm=pm(), overrides=["plus.add=20"])
    status = {r.step_id: r.status for r in changed}
    assert status == {"src": "up to date", "other": "up to date", "plus": "computed", "both": "computed"}
    assert pq.read_table(ws / "both" / "data.parquet")["x"].to_pylist() == [21.0, 22.0, 23.0, 24.0]


def test_failed_step_leaves_nothing_and_rerun_completes(tmp_path):
    body = """
    name: f
    workspace: ws
    steps:
      src: {uses: analyses.toy_source}
      boom: {uses: analyses.toy_fail, input: src}
    """
    p = write(tmp_path, body)
    ws = tmp_path / "ws"
    with pytest.raises(PipelineError, match="step 'boom'.*toy failure"):
        run_pipeline(p, pm=pm())
    assert (ws / "src" / "_manifest.json").is_file()
    assert not (ws / "boom").exists()
    assert not (ws / ".mocapflow" / "tmp").exists() or not any((ws / ".mocapflow" / "tmp").iterdir())
    reports = run_pipeline(p, pm=pm(), overrides=["boom.fail=false"])
    assert [r.status for r in reports] == ["up to date", "computed"]


def test_interrupted_run_leftovers_are_never_read(tmp_path):
    p = write(tmp_path, CHAIN)
    ws = tmp_path / "ws"
    run_pipeline(p, pm=pm())
    own = ws / ".mocapflow"
    assert (own / "CREATED-BY-MOCAPFLOW").is_file()
    # simulate a kill in the middle of writing a step and during a swap
    (own / "tmp" / "plus-dead").mkdir(parents=True)
    (own / "tmp" / "plus-dead" / "data.parquet").write_bytes(b"garbage")
    (own / "trash" / "both-dead").mkdir(parents=True)
    reports = run_pipeline(p, pm=pm(), overrides=["plus.add=3"])
    assert {r.step_id: r.status for r in reports}["both"] == "computed"
    assert pq.read_table(ws / "both" / "data.parquet")["x"].to_pylist() == [4.0, 5.0, 6.0, 7.0]
    assert not (own / "tmp").exists() and not (own / "trash").exists()


def test_a_run_deletes_and_replaces_only_what_it_created(tmp_path):
    """``workspace:`` pointing at a folder the user already had: their ``.tmp``, ``.trash``
    and other files survive every run; a folder named like a step that is not a dataset is
    refused before anything runs, never replaced."""
    p = write(tmp_path, CHAIN.replace("workspace: ws", "workspace: mine"))
    mine = tmp_path / "mine"
    user = {".tmp/draft.txt": b"mine", ".trash/old.bvh": b"keep", "notes.md": b"n", ".mocapflow-like/x": b"x"}
    for rel, data in user.items():
        (mine / rel).parent.mkdir(parents=True, exist_ok=True)
        (mine / rel).write_bytes(data)
    run_pipeline(p, pm=pm())
    run_pipeline(p, pm=pm(), overrides=["plus.add=2"])  # replaces datasets the runner wrote
    assert {rel: (mine / rel).read_bytes() for rel in user} == user
    assert (mine / "both" / "_manifest.json").is_file()

    (mine / "other").rename(tmp_path / "other-dataset")
    (mine / "other").mkdir()
    (mine / "other" / "thesis.tex").write_text("years of work")
    with pytest.raises(ConfigError, match=r"mine/other exists and is not a mocapflow dataset.*step 'other'"):
        run_pipeline(p, pm=pm(), force=True)
    assert (mine / "other" / "thesis.tex").read_text() == "years of work"
    assert (mine / "src" / "_manifest.json").is_file() and "calls.log" in {f.name for f in mine.iterdir()}

    foreign = tmp_path / "foreign"
    (foreign / ".mocapflow").mkdir(parents=True)
    (foreign / ".mocapflow" / "tmp").mkdir()
    with pytest.raises(ConfigError, match="was not created by mocapflow"):
        run_pipeline(p, workspace=foreign, pm=pm())
    assert (foreign / ".mocapflow" / "tmp").is_dir()


def test_overrides_are_validated(tmp_path):
    p = write(tmp_path, CHAIN)
    with pytest.raises(ConfigError, match="no step 'plsu'.*did you mean 'plus'"):
        plan(p, ["plsu.add=1"])
    with pytest.raises(ConfigError, match="STEP.KEY=VALUE"):
        plan(p, ["plus=1"])
    with pytest.raises(ConfigError, match="unknown parameter 'ad'"):
        plan(p, ["plus.ad=1"])


def test_synthetic_motions_through_summary(tmp_path):
    body = """
    name: s
    workspace: ws
    steps:
      motions: {uses: analyses.toy_motions, with: {clips: 2, frames: 30}}
      summary: {uses: analyses.clip_summary, input: motions}
    """
    p = write(tmp_path, body)
    run_pipeline(p, pm=pm())
    t = pq.read_table(tmp_path / "ws" / "summary" / "data.parquet")
    assert t["n_frames"].to_pylist() == [30, 30]
    rom = pq.read_table(tmp_path / "ws" / "summary" / "joint_rom.parquet").to_pylist()
    # synthetic joints swing by ±30° about three axes: ranges are large but below 180°
    knee = [r["rom_deg"] for r in rom if r["joint"] == "lknee"]
    assert len(knee) == 2 and all(20 < k < 180 for k in knee)


def test_executor_from_a_plugin_without_touching_the_runner(tmp_path):
    from toy_components import ExecutorPlugin, RecordingExecutor

    body = """
    name: e
    workspace: ws
    executor: recording
    executor_options: {label: cluster}
    steps:
      motions: {uses: analyses.toy_motions, with: {clips: 2, frames: 10}}
      feats: {uses: analyses.clip_summary, input: motions}
    """
    p = write(tmp_path, body)
    RecordingExecutor.seen.clear()
    run_pipeline(p, pm=get_plugin_manager(entry_points=False, extra=[ToyPlugin(), ExecutorPlugin()]))
    assert RecordingExecutor.seen[-1] == "closed"
    with pytest.raises(ConfigError, match="unknown executor 'recordng'.*did you mean 'recording'"):
        run_pipeline(
            write(tmp_path, body.replace("executor: recording", "executor: recordng"), "q.yaml"),
            pm=get_plugin_manager(entry_points=False, extra=[ToyPlugin(), ExecutorPlugin()]),
        )


def test_killed_run_resumes_with_the_same_outputs(tmp_path):
    """SIGKILL in the middle of a step, then run again: same result, no half-written data read."""
    import os
    import signal
    import subprocess
    import sys
    import time

    body = """
    name: k
    workspace: ws
    steps:
      src: {uses: analyses.toy_source, with: {n: 6}}
      slow: {uses: analyses.toy_slow, input: src, with: {seconds: SECONDS}}
      after: {uses: analyses.toy_add, input: slow}
    """
    p = write(tmp_path, body.replace("SECONDS", "60"))
    tests_dir = Path(__file__).resolve().parents[1]
    script = (
        f"import sys; sys.path.insert(0, {str(tests_dir)!r})\n"
        "from toy_components import ToyPlugin\n"
        "from mocapflow.framework import get_plugin_manager\n"
        "from mocapflow.framework.runner import run_pipeline\n"
        f"run_pipeline({str(p)!r}, pm=get_plugin_manager(entry_points=False, extra=[ToyPlugin()]))\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", script])
    ws = tmp_path / "ws"
    deadline = time.time() + 60
    while not (ws / "slow-started").exists():
        assert proc.poll() is None and time.time() < deadline, "the run ended before the slow step started"
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert (ws / "src" / "_manifest.json").is_file() and not (ws / "slow").exists()
    assert list((ws / ".mocapflow" / "tmp").iterdir()), "the kill should have left a half-written step behind"
    p.write_text(textwrap.dedent(body.replace("SECONDS", "0")))
    reports = {r.step_id: r.status for r in run_pipeline(p, pm=pm())}
    assert reports == {"src": "up to date", "slow": "computed", "after": "computed"}
    assert pq.read_table(ws / "after" / "data.parquet")["x"].to_pylist() == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    assert not (ws / ".mocapflow" / "tmp").exists()


@pytest.mark.parametrize(
    "body, line, words",
    [
        (
            "steps:\n  a: !!python/object/apply:os.system ['touch PWNED']\n",
            3,
            ["unsupported tag", "python/object/apply"],
        ),
        ("steps:\n  a:\n    uses: !custom analyses.toy_source\n", 4, ["unsupported tag '!custom'"]),
        (
            "steps:\n  a: {uses: analyses.toy_source}\n  a: {uses: analyses.toy_add}\n",
            4,
            ["key 'a' appears twice", "line 3"],
        ),
        ("steps: &s\n  a: *s\n", 2, ["alias"]),
    ],
)
def test_yaml_tags_duplicates_and_recursive_aliases_are_config_errors(tmp_path, body, line, words):
    from mocapflow.framework.cli import main

    p = write(tmp_path, "name: bad\n" + body)
    with pytest.raises(ConfigError) as err:
        plan(p)
    msg = str(err.value)
    assert f"{p}:{line}" in msg, msg
    for w in words:
        assert w in msg, msg
    assert main(["--no-entry-points", "plan", str(p)]) == 2
    assert not (tmp_path / "PWNED").exists() and not Path("PWNED").exists()


def test_atomic_writes_never_leave_half_a_file(tmp_path):
    from mocapflow.framework import Format
    from mocapflow.framework.workspace import atomic_path

    target = tmp_path / "take.bvh"
    target.write_text("previous")

    class HalfWriter(Format):
        name = "half"

        def write(self, obj, path):
            assert Path(path).suffix == ".bvh" and Path(path).parent == tmp_path
            Path(path).write_text("HIER")  # a crash after the first bytes
            raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        HalfWriter().write_atomic(None, target)
    assert target.read_text() == "previous" and [p.name for p in tmp_path.iterdir()] == ["take.bvh"]
    with atomic_path(target) as tmp:
        tmp.write_text("new")
        assert target.read_text() == "previous"
    assert target.read_text() == "new" and [p.name for p in tmp_path.iterdir()] == ["take.bvh"]
