from __future__ import annotations

import textwrap

import pyarrow.parquet as pq
import pytest
from toy_components import ToyPlugin

from mocapflow.framework import ConfigError, MocapflowError, get_plugin_manager
from mocapflow.framework.catalog import Catalog
from mocapflow.framework.cli import main
from mocapflow.framework.runner import run_pipeline

PIPE = """
name: toy
workspace: ws
steps:
  motions: {uses: analyses.toy_motions, with: {clips: 3, frames: 25}}
  summary: {uses: analyses.clip_summary, input: motions}
  my-src: {uses: analyses.toy_source, with: {n: 3}}
"""


@pytest.fixture
def workspace(tmp_path):
    p = tmp_path / "p.yaml"
    p.write_text(textwrap.dedent(PIPE))
    run_pipeline(p, pm=get_plugin_manager(entry_points=False, extra=[ToyPlugin()]))
    return tmp_path / "ws"


def test_views_and_parameterised_queries(workspace):
    with Catalog(workspace) as cat:
        assert {"motions", "clips", "summary", "summary_joint_rom", "my-src", "my_src"} <= set(cat.views)
        t = cat.query("SELECT clip_id, n_frames FROM clips WHERE n_frames > ? ORDER BY clip_id", [10])
        assert t.column("n_frames").to_pylist() == [25, 25, 25]
        n = cat.query("SELECT count(*) AS n FROM motions m JOIN clips c USING (clip_id)").column("n")[0].as_py()
        assert n == 75
        assert cat.query("SELECT sum(x) AS s FROM my_src").column("s")[0].as_py() == 3.0
        with pytest.raises(MocapflowError, match="SQL error") as err:
            cat.query("SELECT nope FROM clips")
        assert err.type is MocapflowError  # a failed query, not a refused statement (ConfigError)


def test_catalog_is_read_only(workspace):
    before = sorted(p.name for p in workspace.rglob("*"))
    with Catalog(workspace) as cat:
        cat.query("SELECT * FROM clips")
    assert sorted(p.name for p in workspace.rglob("*")) == before


def test_missing_workspace_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        Catalog(tmp_path / "nope")


def test_cli_sql_table_csv_parquet(workspace, tmp_path, capsys):
    assert main(["--no-entry-points", "sql", str(workspace), "SELECT name, n_frames FROM clips ORDER BY name"]) == 0
    out = capsys.readouterr().out
    assert "synthetic0" in out and "(3 rows)" in out
    assert (
        main(["sql", str(workspace), "SELECT clip_id FROM clips WHERE clip_id = ?", "--param", "1", "--format", "csv"])
        == 0
    )
    assert capsys.readouterr().out.split() == ["clip_id", "1"]
    target = tmp_path / "out.parquet"
    assert main(["sql", str(workspace), "SELECT * FROM summary", "--output", str(target)]) == 0
    assert pq.read_table(target).num_rows == 3


def test_cli_errors_have_no_traceback(tmp_path, capsys):
    assert main(["run", str(tmp_path / "missing.yaml")]) == 2
    err = capsys.readouterr().err
    assert "cannot read pipeline" in err and "Traceback" not in err
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: b\nsteps:\n  a: {uses: formats.laod}\n")
    assert main(["plan", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.yaml:3" in err and "did you mean 'formats.load'" in err and "Traceback" not in err
    assert main(["--debug", "plan", str(bad)]) == 2
    assert "Traceback" in capsys.readouterr().err
    assert main(["sql", str(tmp_path), "SELECT 1"]) == 2


def test_cli_plugins_lists_components_and_params(capsys):
    assert main(["--no-entry-points", "plugins"]) == 0
    out = capsys.readouterr().out
    assert "mocapflow.plugins.formats.plugin" in out and "formats.load" in out
    assert "paths:" in out and "on_error" in out


def _tree(ws):
    return {str(p.relative_to(ws)): p.read_bytes() for p in sorted(ws.rglob("*")) if p.is_file()}


@pytest.mark.parametrize(
    "sql",
    [
        "COPY (SELECT 1 AS x) TO '{ws}/summary/data.parquet'",
        "COPY summary TO '{ws}/summary/data.parquet' (FORMAT parquet)",
        "SELECT 1; COPY (SELECT 1) TO '{ws}/summary/data.parquet'",
        "EXPLAIN ANALYZE COPY (SELECT 1) TO '{ws}/summary/data.parquet'",
        "ATTACH '{ws}/new.db' AS other",
        "EXPORT DATABASE '{ws}/exported'",
        "INSTALL httpfs",
        "LOAD httpfs",
        "CREATE TABLE t AS SELECT 1",
        "SET enable_external_access = true",
    ],
)
def test_sql_cannot_write_attach_or_load(workspace, sql):
    before = _tree(workspace)
    with Catalog(workspace) as cat, pytest.raises(ConfigError, match="read-only"):
        cat.query(sql.format(ws=workspace))
    assert _tree(workspace) == before


def test_sql_cannot_read_files_outside_the_workspace(workspace, tmp_path):
    outside = tmp_path / "secret.csv"
    outside.write_text("a,b\n1,2\n")
    (workspace / "summary" / "note.csv").write_text("a\n1\n")
    with Catalog(workspace) as cat:
        for sql in (
            f"SELECT * FROM read_csv('{outside}')",
            f"SELECT * FROM '{outside}'",
            f"SELECT * FROM read_csv('{workspace}/../secret.csv')",
            "SELECT * FROM read_text('/etc/passwd')",
            f"SELECT * FROM glob('{tmp_path}/*')",
        ):
            with pytest.raises(MocapflowError, match="(?s)SQL error.*reads only the datasets"):
                cat.query(sql)
        # the datasets themselves stay readable, through the views and by path
        assert (
            cat.query(f"SELECT count(*) AS n FROM read_parquet('{workspace}/summary/data.parquet')")["n"][0].as_py()
            == 3
        )
        assert cat.query("EXPLAIN SELECT * FROM summary").num_rows >= 1
        assert cat.query("DESCRIBE summary").num_rows > 0


def test_cli_sql_copy_is_refused_and_run_stays_honest(workspace, capsys):
    target = workspace / "summary" / "data.parquet"
    before = target.read_bytes()
    assert main(["--no-entry-points", "sql", str(workspace), f"COPY (SELECT 1) TO '{target}'"]) == 2
    assert "read-only" in capsys.readouterr().err
    assert target.read_bytes() == before
