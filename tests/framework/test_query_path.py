"""One query path (``framework/queries.py``): the same hit with the same numbers in SQL, the
CLI, Python, the report and an export; a printed hit is a valid next query; query ranges
checked at plan time; an empty result says why."""

from __future__ import annotations

import csv
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CMU = ROOT / "examples" / "data" / "cmu"
WALK, OTHER = CMU / "16" / "16_15.amc", CMU / "02" / "02_01.amc"

PIPELINE = """
name: query-path
workspace: {ws}
steps:
  motions:
    uses: formats.load
    with: {{paths: ["{cmu}/02/02_01.amc", "{cmu}/16/16_15.amc"], fps: 30}}
  fe:
    uses: features.end_effectors
    input: motions
    with: {{joints: 5}}
  tree:
    uses: indexes.kdtree
    input: fe
  search:
    uses: matchers.search
    inputs: {{database: tree, query: motions}}
    with: {{queries: ["{query}"], count: 3}}
"""


def _pipeline(d: Path, query: str) -> Path:
    (d / "p.yaml").write_text(textwrap.dedent(PIPELINE.format(ws=d / "ws", cmu=CMU, query=query)))
    return d / "p.yaml"


@pytest.fixture(scope="module")
def ws(tmp_path_factory) -> Path:
    from mocapflow.framework import get_plugin_manager
    from mocapflow.framework.runner import run_pipeline

    d = tmp_path_factory.mktemp("query-path")
    run_pipeline(_pipeline(d, "16_15:120-240"), workspace=d / "ws", pm=get_plugin_manager(entry_points=False))
    return d / "ws"


def _hits(rows) -> list[tuple[str, int, int]]:
    return [(r["clip"], int(r["start_frame"]), int(r["end_frame"])) for r in rows]


def test_the_same_hit_has_the_same_numbers_everywhere(ws, tmp_path, capsys):
    import mocapflow
    from mocapflow.framework.cli import main
    from mocapflow.plugins.report.model import ModelBuilder
    from mocapflow.plugins.report.plugin import workspace_tables

    # SQL (the step's table, through DuckDB)
    assert main(["sql", str(ws), "SELECT c.name AS clip, m.start_frame, m.end_frame, m.start_s FROM search m "
                 "JOIN clips c USING (clip_id) ORDER BY m.rank", "--format", "csv"]) == 0  # fmt: skip
    sql = list(csv.DictReader(capsys.readouterr().out.splitlines()))
    # the CLI (in-process search, CSV out)
    out = tmp_path / "hits.csv"
    argv = ["search", "--db", str(ws), "--query", "16_15:120-240", "--count", "3", "--no-server", "--out", str(out)]
    assert main(argv) == 0
    capsys.readouterr()
    with open(out) as f:
        cli = list(csv.DictReader(f))
    # Python
    py = mocapflow.Database([OTHER, WALK]).search(mocapflow.read(WALK).slice(120, 240), count=3).to_pylist()
    # the report
    datasets, clips, rejects = workspace_tables(ws)
    view = ModelBuilder(datasets, clips, rejects).retrieval(datasets["search"])
    report = [(h["clip"], *map(int, h["frames"].strip("[)").split(", "))) for h in view["hits"]]
    # an export
    assert main(["export", str(ws), "--output", str(tmp_path / "clips")]) == 0
    with open(tmp_path / "clips" / "index.csv") as f:
        export = [(r["clip"], int(r["start_frame"]), int(r["end_frame"])) for r in csv.DictReader(f)]

    want = _hits(sql)
    assert want and want == _hits(cli) == _hits(py) == report == export
    assert [float(r["start_s"]) for r in sql] == pytest.approx([r["start_frame"] / 120 for r in py])
    assert view["queries"][0]["frames"] == "[120, 240)"  # the query as typed: frames of its file


def test_a_printed_hit_is_a_valid_next_query_that_excludes_itself(ws, tmp_path, capsys):
    from mocapflow.framework.cli import main

    out = tmp_path / "first.csv"
    argv = ["search", "--db", str(ws), "--query", "16_15:120-240", "--no-server", "--out", str(out)]
    assert main(argv) == 0
    capsys.readouterr()
    with open(out) as f:
        best = next(csv.DictReader(f))
    nxt = f"{best['clip']}:{best['start_frame']}-{best['end_frame']}"
    again = tmp_path / "again.csv"
    argv = ["search", "--db", str(ws), "--query", nxt, "--no-server", "--out", str(again)]
    assert main(argv) == 0
    assert "its own span excluded" in capsys.readouterr().out
    a, b = int(best["start_frame"]), int(best["end_frame"])
    with open(again) as f:
        for r in csv.DictReader(f):  # nothing overlaps the hit that served as query
            assert r["clip"] != best["clip"] or int(r["end_frame"]) <= a or int(r["start_frame"]) >= b
    # an empty answer says why
    assert main(["search", "--db", str(ws), "--query", nxt, "--no-server", "--min-span", "10"]) == 0
    assert "0 matches" in (said := capsys.readouterr().out) and "shorter than min_span" in said
    argv += ["--exclude-self", "off"]
    assert main(argv) == 0
    capsys.readouterr()
    with open(again) as f:
        first = next(csv.DictReader(f))
    assert (first["clip"], int(first["start_frame"]), int(first["end_frame"])) == (best["clip"], a, b)


def test_a_query_span_past_its_take_fails_at_plan_naming_the_rate(tmp_path):
    from mocapflow.framework import get_plugin_manager
    from mocapflow.framework.errors import ConfigError
    from mocapflow.framework.runner import plan_pipeline

    with pytest.raises(ConfigError, match=r"outside the clip's 471 frames \(frames of the take's own file, at 120 fps"):
        plan_pipeline(_pipeline(tmp_path, "16_15:400-500"), pm=get_plugin_manager(entry_points=False))
    plan_pipeline(_pipeline(tmp_path, "16_15:400-471"), pm=get_plugin_manager(entry_points=False))


def test_an_empty_result_says_why_and_exclude_self_false_works():
    import mocapflow

    walk = mocapflow.read(WALK)
    db = mocapflow.Database([walk.slice(0, 100).with_arrays(metadata={}), walk], fps=None)  # no path: not "own"
    hits = db.search(walk, count=3, min_span=0.9)  # the whole take, itself excluded; the other 100 frames too short
    assert len(hits) == 0 and "shorter than min_span" in hits.reason and hits.reason in repr(hits)
    own = db.search(walk, count=1, exclude_self=False).to_pylist()
    assert (own[0]["clip"], own[0]["start_frame"], own[0]["end_frame"]) == ("16_15", 0, walk.n_frames)
    whole = mocapflow.Database([walk], fps=None).search(walk, count=1, exclude_self="clip")
    assert len(whole) == 0 and "every database frame is the query's own" in whole.reason
    with pytest.warns(DeprecationWarning, match="path_analysis"):
        assert own and hits["analysis_path"] is not None


def test_compare_workspaces_reports_renamed_columns_and_changed_frames(ws, tmp_path, capsys):
    import shutil

    import pyarrow.parquet as pq
    from compare_workspaces import main as compare

    assert compare([str(ws), str(ws)]) == 0
    out = capsys.readouterr().out.splitlines()[-1]
    n = out.split()[0]
    assert out.startswith(f"{n} of {n} common tables identical")
    other = tmp_path / "other"
    shutil.copytree(ws, other)
    t = pq.read_table(other / "search" / "data.parquet")
    pq.write_table(
        t.rename_columns(["path" if c == "path_analysis" else c for c in t.column_names]),
        other / "search" / "data.parquet",
    )
    assert compare([str(ws), str(other)]) == 0
    out = capsys.readouterr().out
    assert "search/data.parquet: columns only in old: ['path_analysis']; columns only in new: ['path']" in out


def test_the_parameters_stay_within_150():
    import contextlib
    import io

    from mocapflow.framework.cli import main

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(["--no-entry-points", "plugins", "--count-params"]) == 0
    total = int(buf.getvalue().strip().splitlines()[-1].split()[3])
    assert 0 < total <= 150


@pytest.mark.parametrize("name", ["search", "sdtw", "lng", "logical"])
def test_builtin_matchers_rank_around_the_excluded_span(name):
    from mocapflow.framework import load_registries
    from mocapflow.framework.conformance import rows_of_query, synthetic_space

    cls = load_registries(kinds=["matchers"], entry_points=False)["matchers"].get(name)
    matcher = cls({"count": 5, **({"exact": False} if name == "lng" else {})})
    space, query = synthetic_space()
    lo, hi = rows_of_query(space)
    res = matcher.match(query, space.excluding((lo, hi)))
    assert len(res) and not ((res.start <= hi) & (res.end > lo)).any()
