"""The framework against hostile input: YAML alias bombs, plugins that raise SystemExit or
KeyboardInterrupt, out-of-range options and malformed server requests, stalled server
clients, a regular file where the server's socket goes, runaway SQL, a cluster that cannot
start."""

from __future__ import annotations

import argparse
import json
import socket
import textwrap
import threading
import time

import pytest
from toy_components import ToyPlugin

from mocapflow.framework import get_plugin_manager
from mocapflow.framework import plugins as plugins_mod
from mocapflow.framework.cli import main
from mocapflow.framework.config import load_pipeline
from mocapflow.framework.errors import ConfigError, PipelineError
from mocapflow.framework.plugins import build_registries, hookimpl
from mocapflow.framework.runner import run_pipeline

PIPE = """
name: toy
workspace: ws
steps:
  motions: {uses: analyses.toy_motions, with: {clips: 2, frames: 20}}
  summary: {uses: analyses.clip_summary, input: motions}
"""


# --- YAML alias bombs ------------------------------------------------------------------------
def _bomb(levels: int = 9) -> str:
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    for i in range(1, levels):
        lines.append(f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]")
    lines.append(f"name: bomb\nsteps:\n  s: {{uses: analyses.toy_source, with: {{n: *a{levels - 1}}}}}")
    return "\n".join(lines) + "\n"


def test_yaml_alias_bomb_refused_fast_with_file_and_line(tmp_path):
    p = tmp_path / "bomb.yaml"
    p.write_text(_bomb())
    assert p.stat().st_size < 1200  # ~1 kB expanding to 9**9 values
    t0 = time.perf_counter()
    with pytest.raises(ConfigError, match=r"bomb\.yaml:\d+: anchors and aliases expand to more than 100000"):
        load_pipeline(p)
    assert time.perf_counter() - t0 < 10


def test_yaml_aliases_within_the_bound_still_work(tmp_path):
    p = tmp_path / "ok.yaml"
    p.write_text(
        "name: ok\nsteps:\n  a: {uses: analyses.toy_source, with: &v {n: 3}}\n"
        "  b: {uses: analyses.toy_source, with: *v}\n"
    )
    assert load_pipeline(p).config.steps["b"].with_ == {"n": 3}


def test_cli_plan_of_a_bomb_exits_2(tmp_path, capsys):
    p = tmp_path / "bomb.yaml"
    p.write_text(_bomb())
    assert main(["--no-entry-points", "plan", str(p)]) == 2
    assert "bomb.yaml:" in capsys.readouterr().err


def test_set_value_bomb_refused():
    from mocapflow.framework.config import apply_overrides, parse_pipeline

    src = parse_pipeline(textwrap.dedent(PIPE))
    nested = "&a0 [x,x,x,x,x,x,x,x,x]"
    for i in range(1, 8):  # each level: its anchor's list and 8 aliases of the previous one
        nested = f"&a{i} [{', '.join([nested] + [f'*a{i - 1}'] * 8)}]"
    with pytest.raises(ConfigError, match="--set .*expand"):
        apply_overrides(src, [f"motions.clips={nested}"])


# --- hostile plugins --------------------------------------------------------------------------
class _EP:
    def __init__(self, name, load):
        self.name, self._load = name, load

    def load(self):
        return self._load()


def _entry_points(monkeypatch, *eps):
    monkeypatch.setattr(plugins_mod.metadata, "entry_points", lambda group=None: list(eps))


@pytest.mark.parametrize("exc", [SystemExit(7), KeyboardInterrupt()])
def test_plugin_raising_at_import_is_reported_by_name(monkeypatch, capsys, exc):
    def boom():
        raise exc

    _entry_points(monkeypatch, _EP("evil", boom))
    assert main(["plugins"]) == 0
    out = capsys.readouterr().out
    assert "BROKEN plugin 'evil'" in out and type(exc).__name__ in out


class _ExitInHook:
    @hookimpl
    def register_analyses(self):
        raise SystemExit(5)


class _ExitBeforeStep(ToyPlugin):
    @hookimpl
    def before_step(self, step_id, component, workspace):
        raise SystemExit(9)


def test_plugin_raising_systemexit_in_a_registration_hook_is_skipped():
    pm = get_plugin_manager(entry_points=False, extra=[_ExitInHook()])
    regs = build_registries(pm)
    assert "analyses.clip_summary" in set(regs.keys())
    assert any("SystemExit" in f.error for f in pm.failures)


def test_plugin_raising_systemexit_in_a_lifecycle_hook_fails_the_run_with_our_status(tmp_path, monkeypatch, capsys):
    p = tmp_path / "p.yaml"
    p.write_text(textwrap.dedent(PIPE))
    _entry_points(monkeypatch, _EP("evil", _ExitBeforeStep))
    assert main(["run", str(p)]) == 2
    err = capsys.readouterr().err
    assert "'evil'" in err and "SystemExit" in err and "before_step" in err


def test_component_raising_systemexit_fails_its_step(tmp_path):
    from mocapflow.framework.components import Analysis, StepOutput

    class Quitter(Analysis):
        name = "quitter"
        inputs = {}

        def run(self, inputs, ctx):
            raise SystemExit(4)

    class P:
        @hookimpl
        def register_analyses(self):
            return [Quitter]

    p = tmp_path / "p.yaml"
    p.write_text("name: q\nworkspace: ws\nsteps:\n  q: {uses: analyses.quitter}\n")
    with pytest.raises(PipelineError, match="SystemExit"):
        run_pipeline(p, pm=get_plugin_manager(entry_points=False, extra=[P()]))
    assert StepOutput  # the import is the component API


# --- options and requests ---------------------------------------------------------------------
@pytest.mark.parametrize(
    "argv",
    [
        ["search", "--db", "ws", "--query", "q.bvh", "--count", "0"],
        ["search", "--db", "ws", "--query", "q.bvh", "-k", "0"],
        ["search", "--db", "ws", "--query", "q.bvh", "--min-span", "-1"],
        ["search", "--db", "ws", "--query", "q.bvh", "--idle-timeout", "0"],
        ["run", "p.yaml", "--jobs", "-1"],
        ["run", "p.yaml", "--wait", "-5"],
        ["sql", "ws", "SELECT 1", "--max-rows", "-1"],
        ["sql", "ws", "SELECT 1", "--timeout", "-1"],
    ],
)
def test_out_of_range_options_exit_2_with_a_message(argv, capsys):
    with pytest.raises(SystemExit) as ex:
        main(["--no-entry-points", *argv])
    assert ex.value.code == 2
    err = capsys.readouterr().err
    assert "expected" in err and "internal error" not in err


def _session_with_matchers():
    from mocapflow.framework import load_registries
    from mocapflow.plugins.similarity.search.search_command import SearchSession

    s = SearchSession.__new__(SearchSession)
    s.regs = load_registries(kinds=("matchers",), entry_points=False)
    return s


def test_matcher_options_beyond_their_bounds_are_config_errors():
    s = _session_with_matchers()
    base = {"matcher": "search", "count": 10, "k": None, "min_span": None, "rank_by": None, "paper": None}
    with pytest.raises(ConfigError, match=r"--min-span 11.0: .*less than or equal to 10"):
        s.matcher(argparse.Namespace(**{**base, "min_span": 11.0}))
    with pytest.raises(ConfigError, match=r"--count 0"):
        s.matcher(argparse.Namespace(**{**base, "count": 0}))
    with pytest.raises(ConfigError, match=r"-k 0"):
        s.matcher(argparse.Namespace(**{**base, "matcher": "lng", "k": 0}))


class _FakeSession:
    """What the server's request handling needs of a session (no workspace)."""

    def __init__(self, delay=0.0):
        self.seen, self.delay = [], delay
        self.idx = argparse.Namespace(step="index")

    def is_stale(self):
        return False

    def answer(self, args, cwd, out, err):
        time.sleep(self.delay)
        self.seen.append(args)
        print(f"count={args.count} matcher={args.matcher}", file=out)
        return 0


@pytest.mark.parametrize(
    "raw, rc, text",
    [
        (b"not json", 2, "malformed request"),
        (b"[1, 2]", 2, "malformed request"),
        (json.dumps({"args": {"query": "q.bvh", "count": "ten"}, "cwd": "/"}).encode(), 2, "'count': expected int"),
        (json.dumps({"args": {"query": "q.bvh", "count": True}, "cwd": "/"}).encode(), 2, "'count': expected int"),
        (json.dumps({"args": {}, "cwd": "/"}).encode(), 2, "--query is required"),
        # an older client: no count, no matcher -> the CLI's defaults
        (json.dumps({"args": {"query": "q.bvh"}, "cwd": "/"}).encode(), 0, "count=10 matcher=search"),
    ],
)
def test_server_requests_checked(raw, rc, text):
    from mocapflow.plugins.similarity.search.search_server import _handle

    reply = _handle([_FakeSession()], raw, _FakeSession)
    assert reply["rc"] == rc
    assert text in reply["stdout"] + reply["stderr"] and "internal error" not in reply["stderr"]


def test_server_refuses_to_delete_a_regular_file_named_like_its_socket(tmp_path):
    from mocapflow.plugins.similarity.search.search_server import SOCKET_NAME, _remove_stale_socket

    f = tmp_path / SOCKET_NAME
    f.write_text("my notes")
    with pytest.raises(ConfigError, match="not a socket"):
        _remove_stale_socket(f)
    assert f.read_text() == "my notes"
    f.unlink()
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.bind(str(f))
    s.close()  # a stale socket: removed
    _remove_stale_socket(f)
    assert not f.exists()


def test_a_stalled_client_does_not_block_others(tmp_path, monkeypatch):
    from mocapflow.plugins.similarity.search import search_server as srv

    monkeypatch.setattr(srv, "warm_up", lambda s: 0.0)
    monkeypatch.setattr(srv, "REQUEST_TIMEOUT", 30.0)
    sock = tmp_path / srv.SOCKET_NAME
    args = argparse.Namespace(db=str(tmp_path), index=None, idle_timeout=2.0, no_entry_points=True, block=[])
    t = threading.Thread(target=srv.serve, args=(args, lambda *a, **k: _FakeSession()), daemon=True)
    t.start()
    for _ in range(200):
        if sock.exists():
            break
        time.sleep(0.05)
    stalled = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stalled.connect(str(sock))  # connects, sends half a request, never finishes
    stalled.sendall(b'{"args": ')
    t0 = time.perf_counter()
    c = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    c.settimeout(10)
    c.connect(str(sock))
    c.sendall(json.dumps({"args": {"query": "q.bvh"}, "cwd": "/"}).encode())
    c.shutdown(socket.SHUT_WR)
    reply = json.loads(srv._recv_all(c).decode())
    took = time.perf_counter() - t0
    c.close()
    stalled.close()
    assert reply["rc"] == 0 and "count=10" in reply["stdout"]
    assert took < 5.0  # answered while the stalled client still held its connection
    t.join(10)  # idle for --idle-timeout: the server stops and removes its socket
    assert not t.is_alive() and not sock.exists()


# --- SQL limits -------------------------------------------------------------------------------
@pytest.fixture
def workspace(tmp_path):
    p = tmp_path / "p.yaml"
    p.write_text(textwrap.dedent(PIPE))
    run_pipeline(p, pm=get_plugin_manager(entry_points=False, extra=[ToyPlugin()]))
    return tmp_path / "ws"


def test_sql_timeout_stops_a_runaway_query(workspace, capsys):
    slow = "SELECT count(*) FROM range(100000000000) a"
    t0 = time.perf_counter()
    assert main(["--no-entry-points", "sql", str(workspace), slow, "--timeout", "0.5"]) == 1
    assert time.perf_counter() - t0 < 15
    assert "longer than 0.5 s" in capsys.readouterr().err


def test_sql_memory_limit_bounds_the_result(workspace, capsys):
    big = "SELECT range AS x, repeat('y', 100) AS s FROM range(3000000)"
    assert main(["--no-entry-points", "sql", str(workspace), big, "--memory-limit", "64MB", "--format", "csv"]) == 1
    assert "memory limit" in capsys.readouterr().err
    with pytest.raises(ConfigError, match="memory size"):
        from mocapflow.framework.catalog import Catalog

        Catalog(workspace, memory_limit="lots")


# --- executors --------------------------------------------------------------------------------
def test_dask_cluster_that_cannot_start_is_named(monkeypatch):
    distributed = pytest.importorskip("distributed")
    from mocapflow.plugins.executors.dask_cluster import DaskExecutor

    def nanny_fails(*a, **k):
        raise RuntimeError("Nanny failed to start.")

    monkeypatch.setattr(distributed, "LocalCluster", nanny_fails)
    ex = DaskExecutor(jobs=2)
    with pytest.raises(PipelineError, match="executor dask: .*failed to start: RuntimeError: Nanny failed to start"):
        ex.client  # noqa: B018 - connecting is the point
    ex.close()
