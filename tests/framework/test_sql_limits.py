"""``mocapflow sql`` limits hold for any query: the query runs in a child process whose
address space is capped and which is killed past ``--timeout``; the message names the limit."""

from __future__ import annotations

import os
import signal
import textwrap
import time

import pytest
from toy_components import ToyPlugin

from mocapflow.framework import catalog, get_plugin_manager
from mocapflow.framework.cli import main
from mocapflow.framework.errors import MocapflowError
from mocapflow.framework.runner import run_pipeline

PIPE = """
name: toy
workspace: ws
steps:
  motions: {uses: analyses.toy_motions, with: {clips: 2, frames: 20}}
  summary: {uses: analyses.clip_summary, input: motions}
"""


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("sqlws")
    p = tmp / "p.yaml"
    p.write_text(textwrap.dedent(PIPE))
    run_pipeline(p, pm=get_plugin_manager(entry_points=False, extra=[ToyPlugin()]))
    return tmp / "ws"


def test_a_string_larger_than_the_memory_limit_is_stopped(workspace, capsys):
    # DuckDB's own memory_limit does not cover one huge string: without the address-space cap
    # this query takes 600 MB and answers
    t = time.perf_counter()
    rc = main(["sql", str(workspace), "SELECT length(repeat('x', 600000000)) AS n", "--memory-limit", "100MB"])
    err = capsys.readouterr().err
    assert rc == 1 and "memory limit" in err and "--memory-limit" in err, err
    assert time.perf_counter() - t < 10


def test_normal_queries_keep_their_output(workspace, capsys):
    assert main(["sql", str(workspace), "SELECT clip_id, name FROM summary ORDER BY clip_id", "--format", "csv"]) == 0
    assert capsys.readouterr().out.splitlines() == ["clip_id,name", '0,"synthetic0"', '1,"synthetic1"']
    assert main(["sql", str(workspace), "SELECT ? AS a", "--param", "7"]) == 0
    assert "(1 row)" in capsys.readouterr().out
    assert main(["sql", str(workspace), "SELECT * FROM nowhere"]) == 1
    assert "SQL error" in capsys.readouterr().err
    assert main(["sql", str(workspace), "DROP VIEW summary"]) == 2
    assert "read-only" in capsys.readouterr().err


def _sleeps(conn, *args):
    time.sleep(60)


def _dies(conn, *args):
    os.kill(os.getpid(), signal.SIGKILL)  # as the kernel ends a process at its limit


def test_a_query_that_ignores_the_interrupt_is_killed(workspace, monkeypatch):
    monkeypatch.setattr(catalog, "_query_child", _sleeps)
    monkeypatch.setattr(catalog, "QUERY_KILL_GRACE_S", 0.2)
    t = time.perf_counter()
    with pytest.raises(MocapflowError, match=r"longer than 0.5 s and was killed \(--timeout"):
        catalog.limited_query(workspace, "SELECT 1", timeout=0.5, memory_limit="1GB")
    assert time.perf_counter() - t < 5


def test_a_query_process_that_dies_names_the_memory_limit(workspace, monkeypatch):
    monkeypatch.setattr(catalog, "_query_child", _dies)
    with pytest.raises(MocapflowError, match=r"SIGKILL\) at its memory limit \(1,024 MiB; --memory-limit"):
        catalog.limited_query(workspace, "SELECT 1", timeout=5, memory_limit="1GB")
