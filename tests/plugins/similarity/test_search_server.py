"""`mocapflow search` start-up paths: the kd-tree's memory-mapped row sidecars,
registries built for a few kinds only, and the search server giving the same answers as a
search in the calling process."""

from __future__ import annotations

import os
import textwrap
import threading
import time
from argparse import Namespace

import numpy as np
import pytest

from mocapflow.framework import load_registries


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    from conftest import EXAMPLES_DATA

    if not (EXAMPLES_DATA / "cmu").is_dir():
        pytest.skip("examples/data/cmu is absent")
    from mocapflow.framework.runner import run_pipeline

    root = tmp_path_factory.mktemp("srv")  # short: a Unix socket path holds ~100 bytes
    p = root / "p.yaml"
    p.write_text(
        textwrap.dedent(f"""
        name: s
        workspace: {root / "ws"}
        steps:
          motions: {{uses: formats.load, with: {{paths: ["{EXAMPLES_DATA}/cmu/**/*.amc"], fps: 30}}}}
          fe15: {{uses: features.end_effectors, input: motions, with: {{joints: 5}}}}
          tree: {{uses: indexes.kdtree, input: fe15}}
    """)
    )
    run_pipeline(p, echo=lambda s: None)
    return root / "ws"


def test_registries_of_some_kinds_only():
    regs = load_registries(entry_points=False, kinds=("indexes", "matchers"))
    assert "kdtree" in regs["indexes"] and "search" in regs["matchers"]
    assert not list(regs["analyses"]) and not list(regs["cleaners"]) and not list(regs.executors)
    full = load_registries(entry_points=False)
    assert set(full["matchers"].names()) == set(regs["matchers"].names()) and list(full["analyses"])


def test_kdtree_rows_equal_the_features_dataset(workspace):
    """The pipeline's kd-tree keeps no copy of the features: its rows are the features dataset's."""
    from mocapflow.framework.datasets import read_datasets

    ds = read_datasets(workspace)
    index = ds["tree"].index(load_registries(entry_points=False))
    x, clip_id, frame = index.rows()
    fm = ds["fe15"].features()
    assert not list((workspace / "tree" / "index").glob("rows_*.npy"))
    assert not (workspace / "tree" / "index" / "data.npy").exists()
    np.testing.assert_array_equal(x, fm.x)
    np.testing.assert_array_equal(clip_id, fm.clip_id)
    np.testing.assert_array_equal(frame, fm.frame)


def _search(ws, *extra):
    from mocapflow.framework.cli import main

    return main(["--no-entry-points", "search", "--db", str(ws), "--count", "4", *extra])


def test_server_answers_as_the_process_does(workspace, capsys, tmp_path):
    from conftest import EXAMPLES_DATA

    from mocapflow.plugins.similarity.search import search_server

    query = ["--query", f"{EXAMPLES_DATA}/cmu/16/16_15.amc:1s-3s"]
    assert _search(workspace, *query, "--no-server") == 0
    local = capsys.readouterr().out
    assert _search(workspace, *query, "--no-server", "--mode", "fast") == 0
    fast_local = capsys.readouterr().out
    assert "matchers.search (fast)" in fast_local and "matchers.search (exact)" in local
    args = Namespace(db=str(workspace), index=None, no_entry_points=True, block=[], idle_timeout=1.0)
    from mocapflow.plugins.similarity.search.search_command import SearchSession

    server = threading.Thread(target=search_server.serve, args=(args, SearchSession))
    server.start()
    sock = search_server.socket_path(workspace)
    for _ in range(600):
        if sock.exists():
            break
        time.sleep(0.05)
    assert sock.exists() and (sock.stat().st_mode & 0o777) == 0o600
    calls = []
    real_ask = search_server.ask
    search_server.ask = lambda a: calls.append(1) or real_ask(a)
    try:
        assert _search(workspace, *query) == 0
        served = capsys.readouterr().out
        assert _search(workspace, *query, "--mode", "fast") == 0  # the mode reaches the server
        assert capsys.readouterr().out == fast_local
        # relative paths are the client's: --out lands in its working directory
        cwd = os.getcwd()
        os.chdir(tmp_path)
        try:
            assert _search(workspace, *query, "--out", "m.csv") == 0
        finally:
            os.chdir(cwd)
        assert (tmp_path / "m.csv").is_file()
        # errors come back with the CLI's message and exit status
        assert _search(workspace, "--query", "nonexistent.amc") == 2
        assert "neither a clip nor a file" in capsys.readouterr().err
    finally:
        search_server.ask = real_ask
        server.join(30)
    assert calls == [1, 1, 1, 1] and served == local
    assert not server.is_alive() and not sock.exists()  # idle timeout: stopped, socket removed


def test_without_sidecars_and_stale_sessions(workspace, capsys, tmp_path):
    import shutil

    from conftest import EXAMPLES_DATA

    from mocapflow.plugins.similarity.search.search_command import SearchSession
    from mocapflow.plugins.similarity.search.search_server import _handle

    ws = tmp_path / "old"
    shutil.copytree(workspace, ws)
    query = ["--query", f"{EXAMPLES_DATA}/cmu/16/16_15.amc:1s-3s"]
    assert _search(ws, *query, "--no-server") == 0
    with_sidecars = capsys.readouterr().out
    for f in (ws / "tree" / "index").glob("rows_*.npy"):
        f.unlink()  # an index saved before the sidecars existed: features read from Parquet
    assert _search(ws, *query, "--no-server") == 0
    assert capsys.readouterr().out == with_sidecars
    box = [SearchSession(ws, entry_points=False)]
    assert not box[0].is_stale()
    first = box[0]
    manifest = ws / "tree" / "_manifest.json"
    manifest.write_text(manifest.read_text() + " ")  # the index step was recomputed
    req = {
        "args": {
            "query": query[1],
            "index": None,
            "matcher": "search",
            "count": 4,
            "min_span": None,
            "rank_by": None,
            "paper": None,
            "k": None,
            "plot": None,
            "out": None,
        },
        "cwd": str(tmp_path),
    }
    import json

    reply = _handle(box, json.dumps(req).encode(), lambda: SearchSession(ws, entry_points=False))
    assert reply["rc"] == 0 and reply["stdout"] == with_sidecars and box[0] is not first
    req["args"]["index"] = "other"  # a server of another index step declines
    assert _handle(box, json.dumps(req).encode(), lambda: None) == {"rc": None}


def test_mode_switch(workspace, capsys):
    """`--mode exact` is the default search; `--mode fast` answers through the same command."""
    from conftest import EXAMPLES_DATA

    query = ["--query", f"{EXAMPLES_DATA}/cmu/16/16_15.amc:1s-3s", "--no-server"]
    assert _search(workspace, *query) == 0
    default = capsys.readouterr().out
    assert _search(workspace, *query, "--mode", "exact") == 0
    assert capsys.readouterr().out == default
    assert _search(workspace, *query, "--mode", "fast", "--count", "3") == 0
    assert "matchers.search (fast) on" in capsys.readouterr().out
    assert _search(workspace, *query, "--matcher", "sdtw", "--mode", "fast") == 2
    assert "has no parameter 'mode'" in capsys.readouterr().err
