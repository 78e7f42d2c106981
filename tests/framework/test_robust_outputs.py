"""No command but ``mocapflow run`` writes into a workspace's step folders; the report
copies only regular files of the workspace (no symbolic link followed)."""

from __future__ import annotations

import argparse
import io
import json
import textwrap
from pathlib import Path

import pytest
from toy_components import ToyPlugin

from mocapflow.framework import get_plugin_manager
from mocapflow.framework.cli import main
from mocapflow.framework.errors import ConfigError
from mocapflow.framework.runner import run_pipeline
from mocapflow.framework.workspace import MANIFEST

PIPE = """
name: toy
workspace: ws
steps:
  motions: {uses: analyses.toy_motions, with: {clips: 2, frames: 20}}
  summary: {uses: analyses.clip_summary, input: motions}
"""


@pytest.fixture
def workspace(tmp_path):
    p = tmp_path / "p.yaml"
    p.write_text(textwrap.dedent(PIPE))
    run_pipeline(p, pm=get_plugin_manager(entry_points=False, extra=[ToyPlugin()]))
    return tmp_path / "ws"


def _snapshot(ws: Path) -> dict[str, bytes]:
    return {str(p.relative_to(ws)): p.read_bytes() for p in sorted(ws.rglob("*")) if p.is_file()}


def test_refuse_dataset_path_covers_step_folders_runner_folder_and_links(workspace, tmp_path):
    from mocapflow.framework.output_paths import refuse_dataset_path

    for bad in (
        workspace / "summary" / "data.parquet",
        workspace / "summary",
        workspace / "summary" / "new" / "x.csv",
        workspace / ".mocapflow" / "x.csv",
    ):
        with pytest.raises(ConfigError, match="--out"):
            refuse_dataset_path(bad, "--out")
    link = tmp_path / "link"
    link.symlink_to(workspace / "summary")
    with pytest.raises(ConfigError, match="dataset"):
        refuse_dataset_path(link / "data.parquet", "--out")
    # the workspace root and folders beside it are fine
    assert refuse_dataset_path(workspace / "result.csv", "--out") == workspace / "result.csv"
    assert refuse_dataset_path(tmp_path / "elsewhere" / "r.csv", "-o").name == "r.csv"


@pytest.mark.parametrize("target", ["summary/data.parquet", "summary/new.csv", "motions/clips.parquet"])
def test_sql_output_never_replaces_a_dataset(workspace, capsys, target):
    before = _snapshot(workspace)
    rc = main(
        [
            "--no-entry-points",
            "sql",
            str(workspace),
            "SELECT 1 AS hijacked",
            "--format",
            "parquet",
            "-o",
            str(workspace / target),
        ]
    )
    assert rc == 2
    assert "only `mocapflow run` writes there" in capsys.readouterr().err
    assert _snapshot(workspace) == before


def test_search_out_and_plot_refused_inside_a_dataset_also_through_the_server(workspace):
    from mocapflow.plugins.similarity.search.search_command import SearchSession

    before = _snapshot(workspace)

    # the check runs before the session is needed: an answer (direct or the server's) refuses first
    class Session(SearchSession):
        def __init__(self):  # no workspace needed: the refusal comes first
            self.idx = argparse.Namespace(step="index")

        def is_stale(self):
            return False

    session = Session()
    for opt, key in (("--out", "out"), ("--plot", "plot")):
        args = argparse.Namespace(query="x.bvh", out=None, plot=None)
        setattr(args, key, "summary/data.parquet")
        with pytest.raises(ConfigError, match=opt):
            session.answer(args, workspace, io.StringIO(), io.StringIO())
    from mocapflow.plugins.similarity.search.search_server import _handle

    req = {"args": {"query": "x.bvh", "out": str(workspace / "summary" / "data.parquet")}, "cwd": str(workspace)}
    reply = _handle([session], json.dumps(req).encode(), lambda: session)
    assert reply["rc"] == 2 and "only `mocapflow run`" in reply["stderr"]
    assert _snapshot(workspace) == before


def test_report_output_refused_inside_a_dataset(workspace, capsys):
    before = _snapshot(workspace)
    assert main(["--no-entry-points", "report", str(workspace), "-o", str(workspace / "summary" / "site")]) == 2
    assert "dataset" in capsys.readouterr().err
    assert _snapshot(workspace) == before


def test_clean_outputs_refused_inside_a_dataset(workspace, capsys):
    before = _snapshot(workspace)
    out = str(workspace / "summary" / "clean.bvh")
    assert main(["--no-entry-points", "clean", "take.bvh", "--context", "c.bvh", "--output", out]) == 2
    assert "dataset" in capsys.readouterr().err
    assert _snapshot(workspace) == before


def test_export_output_refused_inside_a_dataset(workspace, capsys):
    before = _snapshot(workspace)
    out = str(workspace / "summary" / "clips")
    assert main(["--no-entry-points", "export", str(workspace), "--step", "summary", "--output", out]) == 2
    assert "dataset" in capsys.readouterr().err
    assert _snapshot(workspace) == before


def test_reconstruct_output_refused_inside_a_dataset(workspace, tmp_path, capsys):
    before = _snapshot(workspace)
    take = tmp_path / "take.trc"
    take.write_text("not read: the output is refused first")
    out = str(workspace / "summary" / "take.bvh")
    assert main(["--no-entry-points", "reconstruct", str(take), "--prior", str(tmp_path), "-o", out]) == 2
    assert "dataset" in capsys.readouterr().err
    assert _snapshot(workspace) == before


def test_report_copies_no_symlinked_plot(workspace, tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text("root:x:0:0")
    (workspace / "summary" / "leak.png").symlink_to(secret)
    (workspace / "summary" / "sub").symlink_to(tmp_path, target_is_directory=True)
    (workspace / "summary" / "real.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    site = tmp_path / "site"
    assert main(["--no-entry-points", "report", str(workspace), "-o", str(site)]) == 0
    copied = {p.name for p in site.rglob("*.png")}
    assert copied == {"real.png"}
    assert not any(b"root:x" in p.read_bytes() for p in site.rglob("*") if p.is_file())
    assert (workspace / "summary" / MANIFEST).is_file()


# --- outputs checked by identity: hard links, links anywhere on the path, links
# inside an output folder; the workspace stays byte-identical after every refusal


def _links(workspace: Path, tmp_path: Path) -> dict[str, Path]:
    """Hostile output targets: other names of the workspace's files and folders."""
    out = tmp_path / "hostile"
    out.mkdir()
    hard = out / "hard.png"
    hard.hardlink_to(workspace / "summary" / "data.parquet")
    (out / "mid").symlink_to(workspace / "summary", target_is_directory=True)
    folder = out / "dir_with_link"
    folder.mkdir()
    (folder / "index.csv").symlink_to(workspace / "summary" / "data.parquet")
    folder2 = out / "dir_with_dir_link"
    folder2.mkdir()
    (folder2 / "q0").symlink_to(workspace / "motions", target_is_directory=True)
    folder3 = out / "dir_with_hard_link"
    folder3.mkdir()
    (folder3 / "index.csv").hardlink_to(workspace / "motions" / MANIFEST)
    return {
        "hard": hard,
        "mid": out / "mid" / "deeper" / "x.png",
        "dir_link": folder,
        "dir_dir_link": folder2,
        "dir_hard_link": folder3,
    }


def test_refuse_dataset_path_by_identity(workspace, tmp_path):
    from mocapflow.framework.output_paths import refuse_dataset_path

    bad = _links(workspace, tmp_path)
    with pytest.raises(ConfigError, match="data.parquet of a mocapflow workspace under another name"):
        refuse_dataset_path(bad["hard"], "--plot", workspaces=[workspace])
    with pytest.raises(ConfigError, match="hard links"):  # the workspace unknown: the link count refuses
        refuse_dataset_path(bad["hard"], "--plot")
    with pytest.raises(ConfigError, match="dataset"):
        refuse_dataset_path(bad["mid"], "--plot")
    for key in ("dir_link", "dir_dir_link", "dir_hard_link"):
        refuse_dataset_path(bad[key] / "new.csv", "-o")  # a new file beside the links is fine
        with pytest.raises(ConfigError, match="-o"):
            refuse_dataset_path(bad[key], "-o", directory=True)
    clean = tmp_path / "clean_dir"
    (clean / "sub").mkdir(parents=True)
    (clean / "sub" / "a.bvh").write_text("x")
    (clean / "sub" / "up").symlink_to(clean, target_is_directory=True)  # a loop: visited once
    assert refuse_dataset_path(clean, "-o", directory=True) == clean


@pytest.mark.parametrize("kind", ["hard", "mid"])
def test_sql_output_through_links_refused(workspace, tmp_path, capsys, kind):
    bad = _links(workspace, tmp_path)
    before = _snapshot(workspace)
    args = ["--no-entry-points", "sql", str(workspace), "SELECT 1 AS x", "--format", "csv", "-o", str(bad[kind])]
    assert main(args) == 2
    assert "--output" in capsys.readouterr().err
    assert _snapshot(workspace) == before


@pytest.mark.parametrize("kind", ["hard", "mid"])
def test_search_plot_and_out_through_links_refused(workspace, tmp_path, kind):
    from mocapflow.plugins.similarity.search.search_command import SearchSession

    bad = _links(workspace, tmp_path)
    before = _snapshot(workspace)

    class Session(SearchSession):
        def __init__(self):
            self.db = workspace
            self.idx = argparse.Namespace(step="index")

    for key in ("out", "plot"):
        args = argparse.Namespace(query="x.bvh", out=None, plot=None)
        setattr(args, key, str(bad[kind]))
        with pytest.raises(ConfigError, match=f"--{key}"):
            Session().answer(args, tmp_path, io.StringIO(), io.StringIO())
    assert _snapshot(workspace) == before


@pytest.mark.parametrize("kind", ["dir_link", "dir_dir_link", "dir_hard_link", "mid"])
def test_export_and_report_into_a_folder_with_links_refused(workspace, tmp_path, capsys, kind):
    bad = _links(workspace, tmp_path)
    before = _snapshot(workspace)
    out = str(bad[kind])
    assert main(["--no-entry-points", "export", str(workspace), "--step", "summary", "-o", out]) == 2
    assert main(["--no-entry-points", "report", str(workspace), "-o", out]) == 2
    err = capsys.readouterr().err
    assert err.count("--output") >= 2 and "Traceback" not in err
    assert _snapshot(workspace) == before


@pytest.mark.parametrize("kind", ["hard", "mid"])
def test_clean_and_reconstruct_through_links_refused(workspace, tmp_path, capsys, kind):
    bad = _links(workspace, tmp_path)
    target = bad[kind].with_suffix(".bvh") if kind == "mid" else bad[kind]
    if kind == "hard":
        target = target.with_name("hard.bvh")
        target.hardlink_to(workspace / "summary" / "data.parquet")
    before = _snapshot(workspace)
    take = tmp_path / "take.trc"
    take.write_text("not read: the output is refused first")
    assert main(["--no-entry-points", "clean", str(take), "--output", str(target)]) == 2
    assert main(["--no-entry-points", "reconstruct", str(take), "--prior", str(tmp_path), "-o", str(target)]) == 2
    assert main(["--no-entry-points", "clean", str(take), "--output", "x.bvh", "--report", str(bad["dir_link"])]) == 2
    capsys.readouterr()
    assert _snapshot(workspace) == before


def test_run_workspace_inside_a_step_folder_refused(workspace, tmp_path):
    p = tmp_path / "p2.yaml"
    p.write_text(textwrap.dedent(PIPE))
    link = tmp_path / "inner"
    link.symlink_to(workspace / "summary", target_is_directory=True)
    before = _snapshot(workspace)
    with pytest.raises(ConfigError, match="dataset"):
        run_pipeline(p, workspace=link / "ws", pm=get_plugin_manager(entry_points=False, extra=[ToyPlugin()]))
    assert _snapshot(workspace) == before
