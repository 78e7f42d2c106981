"""Bad options and requests end as one clear error (exit 1 or 2), never an internal error
(exit 3): each case below was one before its fix."""

from __future__ import annotations

import json
import os
import textwrap

import pytest

from mocapflow.framework.cli import main


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    from conftest import EXAMPLES_DATA

    if not (EXAMPLES_DATA / "cmu").is_dir():
        pytest.skip("examples/data/cmu is absent")
    from mocapflow.framework.runner import run_pipeline

    root = tmp_path_factory.mktemp("opt")
    p = root / "p.yaml"
    p.write_text(
        textwrap.dedent(f"""
        name: s
        workspace: {root / "ws"}
        steps:
          motions: {{uses: formats.load, with: {{paths: ["{EXAMPLES_DATA}/cmu/02/*.amc"], fps: 30}}}}
          fe15: {{uses: features.end_effectors, input: motions, with: {{joints: 5}}}}
          tree: {{uses: indexes.kdtree, input: fe15}}
    """)
    )
    run_pipeline(p, echo=lambda s: None)
    return root / "ws"


def _cli(capsys, *argv: str) -> tuple[int, str]:
    try:
        rc = main(["--no-entry-points", *argv])
    except SystemExit as exc:  # argparse refusing an option
        rc = int(exc.code or 0)
    err = capsys.readouterr().err
    assert "internal error" not in err, err
    return rc, err


def test_reconstruct_k_zero(capsys, tmp_path):
    rc, err = _cli(capsys, "reconstruct", "x.trc", "--prior", str(tmp_path), "-o", str(tmp_path / "a.bvh"), "-k", "0")
    assert rc == 2 and "-k: expected an integer >= 2" in err


def test_absurd_step_ids(capsys, tmp_path):
    for sid in ("a" * 300, "a" * 101):
        p = tmp_path / "p.yaml"
        p.write_text(f"name: t\nworkspace: ws\nsteps:\n  {sid}: {{uses: analyses.clip_summary}}\n")
        rc, err = _cli(capsys, "plan", str(p))
        assert rc == 2 and "characters; at most 100" in err


@pytest.mark.parametrize(
    "argv",
    [
        ["sql", "WS", "SELECT 1", "--timeout", "99999999999999999999999"],
        ["sql", "WS", "SELECT 1", "--max-rows", "99999999999999999999999"],
        ["sql", "x" * 300, "SELECT 1"],
        ["export", "x" * 300],
        ["report", "x" * 300],
        ["search", "--db", "WS", "--query", "02_01.amc:20-80", "--out", "/", "--no-server"],
        ["search", "--db", "WS", "--query", "02_01.amc:20-80", "--out", ".", "--no-server"],
        ["search", "--db", "WS", "--query", "x" * 300, "--no-server"],
        ["search", "--db", "WS", "--query", "02_01.amc:20-80", "-k", "1000000000", "--matcher", "lng", "--no-server"],
        ["search", "--db", "WS", "--query", "02_01.amc:20-80", "--serve", "--idle-timeout", "1e30"],
        ["export", "WS", "-o", "FIFO"],
        ["run", "P", "--workspace", "FIFO"],
        ["run", "FIFO"],
        ["clean", "take.bvh", "--output", "c.bvh", "--report", "FIFO"],
        ["sql", "WS", "SELECT 1", "--format", "csv", "-o", "FIFO"],
        ["search", "--db", "WS", "--query", "02_01:20-80", "--out", "FIFO", "--no-server"],
    ],
)
def test_bad_options_are_clear_errors(workspace, capsys, tmp_path, argv):
    p = tmp_path / "p.yaml"
    p.write_text("name: t\nsteps:\n  motions: {uses: formats.load, with: {paths: ['*.amc']}}\n")
    fifo = tmp_path / "fifo"  # never /dev/null: a command run as root that renamed over it would replace it
    os.mkfifo(fifo)
    argv = [str(workspace) if a == "WS" else str(p) if a == "P" else str(fifo) if a == "FIFO" else a for a in argv]
    rc, err = _cli(capsys, *argv)
    assert rc in (1, 2) and err.startswith(("mocapflow: error:", "usage:")), err
    assert fifo.is_fifo()  # not replaced by a file


def test_server_requests_bounded(workspace):
    from mocapflow.plugins.similarity.search.search_command import SearchSession
    from mocapflow.plugins.similarity.search.search_server import _handle

    box = [SearchSession(workspace, None, entry_points=False)]
    cwd = str(workspace.parent)
    good = {"query": "02_01:20-80"}
    for args, expected in (
        ({**good, "matcher": "lng", "k": 10**9}, "less than or equal to 4096"),
        ({**good, "k": 0}, "'k': expected a number >= 1"),
        ({**good, "count": -1}, "'count': expected a number >= 1"),
        ({**good, "min_span": -1}, "'min_span': expected a number >= 0"),
        ({"query": "x" * 300}, "a name of 300 bytes"),
        ({"query": "a\x00b"}, "NUL"),
        ({**good, "out": "/"}, "is a directory"),
    ):
        reply = _handle(box, json.dumps({"args": args, "cwd": cwd}).encode(), lambda: box[0])
        assert reply["rc"] == 2 and expected in reply["stderr"], (args, reply)
    deep = b"[" * 100_000 + b"]" * 100_000
    reply = _handle(box, deep, lambda: box[0])
    assert reply["rc"] == 2 and "malformed request" in reply["stderr"]
    reply = _handle(box, json.dumps({"args": good, "cwd": cwd}).encode(), lambda: box[0])
    assert reply["rc"] == 0, reply
