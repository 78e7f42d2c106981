"""Two runs on one workspace: the second waits or refuses naming the holder; a killed
run's lock is taken over with a notice. Each test starts real processes."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from toy_components import ToyPlugin

from mocapflow.framework import get_plugin_manager
from mocapflow.framework.errors import LockError
from mocapflow.framework.runner import run_pipeline
from mocapflow.framework.workspace import WorkspaceLock, holder_alive

TESTS = Path(__file__).resolve().parents[1]
GATED = """
name: gated
workspace: ws
steps:
  gate: {uses: analyses.toy_gate}
  src: {uses: analyses.toy_source, with: {n: 3}}
"""


def pm():
    return get_plugin_manager(entry_points=False, extra=[ToyPlugin()])


def start_run(pipeline: Path, wait: float = 0.0) -> subprocess.Popen:
    script = (
        f"import sys; sys.path.insert(0, {str(TESTS)!r})\n"
        "from toy_components import ToyPlugin\n"
        "from mocapflow.framework import get_plugin_manager\n"
        "from mocapflow.framework.errors import LockError\n"
        "from mocapflow.framework.runner import run_pipeline\n"
        "try:\n"
        f"    r = run_pipeline({str(pipeline)!r}, pm=get_plugin_manager(entry_points=False, extra=[ToyPlugin()]),\n"
        f"                     wait={wait!r}, echo=print)\n"
        "    print('STATUS', ' '.join(x.status.replace(' ', '_') for x in r))\n"
        "except LockError as exc:\n"
        "    print('LOCKED', exc); sys.exit(4)\n"
    )
    return subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def wait_for(path: Path, proc: subprocess.Popen, seconds: float = 120) -> None:
    deadline = time.monotonic() + seconds
    while not path.exists():
        if proc.poll() is not None:
            raise AssertionError(f"the run ended early: {proc.stdout.read()}")
        assert time.monotonic() < deadline, f"{path} never appeared"
        time.sleep(0.05)


@pytest.fixture
def pipeline(tmp_path):
    p = tmp_path / "p.yaml"
    p.write_text(textwrap.dedent(GATED))
    return p


def test_second_run_refuses_naming_the_holder_and_leaves_its_work_alone(pipeline, tmp_path):
    ws = tmp_path / "ws"
    first = start_run(pipeline)
    try:
        wait_for(ws / "gate-started", first)
        with pytest.raises(LockError) as err:
            run_pipeline(pipeline, pm=pm())
        msg = str(err.value)
        assert f"pid {first.pid}" in msg and socket.gethostname() in msg and "pipeline 'gated'" in msg, msg
        assert "started 20" in msg and "--wait" in msg
        # the refused run cleaned nothing: the holder's half-written step is still there
        assert any((ws / ".mocapflow" / "tmp").iterdir())
        # a second real process is refused too
        second = start_run(pipeline)
        out, _ = second.communicate(timeout=120)
        assert second.returncode == 4 and f"pid {first.pid}" in out, out
    finally:
        (ws / "gate-open").write_text("1")
        out, _ = first.communicate(timeout=120)
    assert first.returncode == 0 and "STATUS computed computed" in out, out
    assert pq.read_table(ws / "gate" / "data.parquet")["x"].to_pylist() == [1.0]
    assert json.loads((ws / ".mocapflow" / "lock").read_text() or "{}") == {}  # released cleanly


def test_second_run_waits_for_the_first_then_runs(pipeline, tmp_path):
    ws = tmp_path / "ws"
    first = start_run(pipeline)
    try:
        wait_for(ws / "gate-started", first)
        second = start_run(pipeline, wait=300)
        deadline = time.monotonic() + 120
        # it says it waits, naming the holder; then the first finishes and the second runs
        line = ""
        while "waiting" not in line:
            line = second.stdout.readline()
            assert line or second.poll() is None, "the second run ended without waiting"
            assert time.monotonic() < deadline
        assert f"pid {first.pid}" in line, line
        assert second.poll() is None
    finally:
        (ws / "gate-open").write_text("1")
    out1, _ = first.communicate(timeout=120)
    out2, _ = second.communicate(timeout=120)
    assert first.returncode == 0 and "STATUS computed computed" in out1, out1
    assert second.returncode == 0 and "STATUS up_to_date up_to_date" in out2, out2


def test_lock_of_a_killed_run_is_taken_over_with_a_notice(pipeline, tmp_path, caplog):
    ws = tmp_path / "ws"
    first = start_run(pipeline)
    wait_for(ws / "gate-started", first)
    os.kill(first.pid, signal.SIGKILL)
    first.wait()
    record = json.loads((ws / ".mocapflow" / "lock").read_text())
    assert record["pid"] == first.pid and not holder_alive(record)
    (ws / "gate-open").write_text("1")
    reports = run_pipeline(pipeline, pm=pm())
    assert [r.status for r in reports] == ["computed", "computed"]
    assert (
        f"taking over the lock of a run that did not finish (pid {first.pid} on host {socket.gethostname()}"
        in caplog.text
    )
    assert "is no longer running" in caplog.text


def test_without_flock_the_record_decides(tmp_path, monkeypatch):
    """Filesystems without flock: a live holder on this host refuses, a dead one is taken over."""
    monkeypatch.setattr(WorkspaceLock, "_try_flock", lambda self, fd: None)
    ws = tmp_path / "ws"
    with WorkspaceLock(ws, pipeline="one") as lock:
        record = json.loads(lock.path.read_text())
        assert record["pid"] == os.getpid()
        with pytest.raises(LockError, match=f"pid {os.getpid()} on host"):  # its holder (this process) is alive
            WorkspaceLock(ws).acquire()
    # a record of a process that died without releasing: taken over
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (ws / ".mocapflow" / "lock").write_text(
        json.dumps({"pid": dead.pid, "host": socket.gethostname(), "started": "then"})
    )
    with WorkspaceLock(ws) as lock:
        assert json.loads(lock.path.read_text())["pid"] == os.getpid()
    # a record from another host cannot be checked: refused
    (ws / ".mocapflow" / "lock").write_text(json.dumps({"pid": 1, "host": "elsewhere", "started": "then"}))
    with pytest.raises(LockError, match="pid 1 on host elsewhere"):
        WorkspaceLock(ws).acquire()


def test_cli_run_refuses_a_locked_workspace_and_waits_with_wait(tmp_path, capsys):
    from mocapflow.framework.cli import main

    src = next((TESTS.parent / "examples" / "data" / "cmu").rglob("*.amc"))
    p = tmp_path / "p.yaml"
    p.write_text(
        f"name: c\nworkspace: ws\nsteps:\n  motions: {{uses: formats.load, with: {{paths: [{str(src)!r}]}}}}\n"
    )
    with WorkspaceLock(tmp_path / "ws", pipeline="other"):
        assert main(["--no-entry-points", "run", str(p)]) == 1
        err = capsys.readouterr().err
        assert f"is in use by another run (pid {os.getpid()} on host" in err and "pipeline 'other'" in err, err
        assert main(["--no-entry-points", "run", str(p), "--wait", "0.5"]) == 1
        out, err = capsys.readouterr()
        assert "waiting up to 0.5 s" in out and "longer --wait" in err
    assert not (tmp_path / "ws" / "motions").exists()
