"""Logical (iterated) similarity search, and the matcher steps' run() on hand-made datasets."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest
from test_lng import BruteIndex

from mocapflow.framework import StepContext, load_registries
from mocapflow.framework.datasets import MANIFEST, Dataset, feature_table, frame_id_table
from mocapflow.framework.errors import ConfigError
from mocapflow.framework.matching import USER_MATCH_COLUMNS, SearchSpace
from mocapflow.framework.queries import parse_query_spec
from mocapflow.framework.steps import run_step
from mocapflow.plugins.similarity.search.certified import CertifiedSearch
from mocapflow.plugins.similarity.search.lng import LazyNeighborhoodGraph
from mocapflow.plugins.similarity.search.logical import LogicalSearch, logical_search
from mocapflow.plugins.similarity.search.sdtw import SubsequenceDTW


class SavedBrute(BruteIndex):
    name = "saved_brute_test"

    def save(self, directory):
        directory.mkdir(parents=True, exist_ok=True)
        np.save(directory / "x.npy", self.x_)

    @classmethod
    def load(cls, directory):
        return cls().build(np.load(directory / "x.npy"))


def chain_db():
    """Clips holding a motif drifted by 0, 1, 2, 3 units (far filler around it) and one unrelated clip."""
    t = np.linspace(0, 2 * np.pi, 20)
    motif = np.stack([np.sin(t), np.cos(t), t / 3, 0 * t], axis=1)
    drift = np.array([0.0, 0.0, 0.0, 1.0])  # orthogonal to the motif: every cell costs exactly 1 per step
    clips = []
    for c in range(4):
        filler = 50.0 + 10 * c + np.arange(8)[:, None] * np.ones(4)
        clips.append(np.concatenate([filler, motif + c * drift, filler + 5]))
    clips.append(-40.0 + np.cumsum(np.ones((30, 4)), axis=0))
    x = np.concatenate(clips).astype(np.float32)
    clip_id = np.concatenate([np.full(len(c), i) for i, c in enumerate(clips)]).astype(np.int32)
    frame = np.concatenate([np.arange(len(c)) for c in clips]).astype(np.int32)
    return SearchSpace(clip_id, frame, SavedBrute().build(x), x), motif.astype(np.float32)


def test_logical_reaches_what_numerical_misses():
    space, motif = chain_db()
    ceiling = 25.0  # one drift step costs 20 (20 frames x 1 unit), two cost 40
    own = (8, 28)  # the query's own segment in clip 0, half-open
    numerical = logical_search(motif, space, rounds=1, exclude=own, k=64, count=5, max_cost=ceiling)
    assert sorted(set(space.clip_id[numerical.start])) == [1]
    logical = logical_search(motif, space, rounds=5, exclude=own, k=64, count=5, max_cost=ceiling)
    assert sorted(space.clip_id[logical.start]) == [1, 2, 3]
    assert list(logical.round) == [1, 2, 3]
    assert list(logical.source) == [-1, 0, 1]  # each found by the previous one
    for s, e in zip(logical.start, logical.end, strict=True):
        assert (space.frame[s], space.frame[e - 1]) == (8, 27)


def test_logical_stops_and_deduplicates():
    space, motif = chain_db()
    res = logical_search(motif, space, rounds=10, k=64, count=10, max_cost=25.0)
    iv = sorted(zip(res.start, res.end, strict=True))
    assert all(a[1] <= b[0] for a, b in zip(iv, iv[1:], strict=False))  # no overlaps (half-open)
    assert res.round.max() <= 4  # ran out of new segments long before 10 rounds
    capped = logical_search(motif, space, rounds=10, k=64, count=10, max_cost=25.0, max_matches=2)
    assert len(capped) == 2


def write_dataset(path, component, tables, inputs=None, params=None):
    path.mkdir(parents=True, exist_ok=True)
    for name, t in tables.items():
        pq.write_table(t, path / f"{name}.parquet")
    manifest = {
        "step": path.name,
        "component": component,
        "params": params or {},
        "fingerprint": path.name,
        "inputs": {k: {"step": v, "fingerprint": v} for k, v in (inputs or {}).items()},
    }
    (path / MANIFEST).write_text(json.dumps(manifest))
    return Dataset(path)


@pytest.fixture
def workspace(tmp_path):
    space, _ = chain_db()
    regs = load_registries(entry_points=False)
    regs["indexes"].add(SavedBrute, "tests")
    feats = write_dataset(
        tmp_path / "feats", "features.test", {"data": feature_table(space.clip_id, space.frame, space.features)}
    )
    idx_dir = tmp_path / "tree"
    SavedBrute().build(space.features).save(idx_dir / "index")
    tree = write_dataset(
        idx_dir,
        "indexes.saved_brute_test",
        {"data": frame_id_table(space.clip_id, space.frame)},
        inputs={"features": "feats"},
    )
    return tmp_path, regs, feats, tree


def ctx_for(tmp_path, regs, step):
    out = tmp_path / f".tmp-{step}"
    out.mkdir()
    return StepContext(step, out, tmp_path, tmp_path, regs)


@pytest.mark.parametrize(
    "cls,params",
    [
        (CertifiedSearch, {"count": 3, "plots": 1}),
        (LazyNeighborhoodGraph, {"k": 64, "count": 3, "exact": False}),
        (LazyNeighborhoodGraph, {"k": 64, "count": 3, "exact": False, "paper": True}),
        (SubsequenceDTW, {"count": 3}),
        (LogicalSearch, {"k": 64, "count": 3, "max_cost": 25.0, "rank_by": "cost"}),
    ],
)
def test_run_steps_on_datasets(workspace, cls, params):
    tmp_path, regs, feats, tree = workspace
    # the queries are cut from the database's own features: logical keeps them excluded, the
    # others search them too (exclude_self off) and find themselves first
    own = {} if cls is LogicalSearch else {"exclude_self": "off"}
    matcher = cls({**params, **own, "queries": ["0:8-28", "1:8-28"]})
    out = run_step(matcher, {"database": tree, "query": feats}, ctx_for(tmp_path, regs, cls.name))
    data, queries = out.tables["data"], out.tables["queries"]
    assert data.schema.names[: len(USER_MATCH_COLUMNS)] == list(USER_MATCH_COLUMNS)
    assert queries["name"].to_pylist() == ["0:8-28", "1:8-28"]
    rows = data.to_pylist()
    assert rows and all(r["end_frame"] > r["start_frame"] for r in rows)
    for r in rows:  # paths use within-clip analysis frames inside [start, end)
        frames = [p[1] for p in r["path_analysis"]]
        assert min(frames) == r["start_frame_analysis"] and max(frames) == r["end_frame_analysis"] - 1
        # features without source rates: one frame is one row
        assert (r["start_frame"], r["end_frame"]) == (r["start_frame_analysis"], r["end_frame_analysis"])
    if cls is LogicalSearch:  # the query's own segment is excluded
        assert all(not (r["query_id"] == 0 and r["clip_id"] == 0 and r["start_frame"] < 28) for r in rows)
        assert set(data["round"].to_pylist()) >= {1, 2}
    else:
        best = [r for r in rows if r["rank"] == 1]
        assert [(r["clip_id"], r["start_frame"], r["end_frame"]) for r in best] == [(0, 8, 28), (1, 8, 28)]
        assert best[0]["cost"] == pytest.approx(0.0, abs=1e-6)
    if cls is CertifiedSearch:
        pngs = sorted(p.name for p in (tmp_path / ".tmp-search" / "plots").iterdir())
        assert pngs == ["q0_m1.png", "q1_m1.png"]


def test_sdtw_runs_on_a_features_dataset_without_index(workspace):
    tmp_path, regs, feats, tree = workspace
    out = run_step(
        SubsequenceDTW(count=1, queries=["2:8-28"], exclude_self="off"),
        {"database": feats, "query": feats},
        ctx_for(tmp_path, regs, "s"),
    )
    assert out.tables["data"].to_pylist()[0]["clip_id"] == 2


def test_lng_needs_an_index_dataset(workspace):
    tmp_path, regs, feats, tree = workspace
    with pytest.raises(Exception, match="index dataset"):
        run_step(LazyNeighborhoodGraph(), {"database": feats, "query": feats}, ctx_for(tmp_path, regs, "l"))


@pytest.mark.parametrize(
    "text,expected",
    [
        ("walk.amc", ("walk.amc", None, None, False)),
        ("walk.amc:10-40", ("walk.amc", 10, 40, False)),
        ("C:/data/walk.amc:1.5s-3s", ("C:/data/walk.amc", 1.5, 3.0, True)),
        ("odd:name.bvh", ("odd:name.bvh", None, None, False)),
    ],
)
def test_query_specs(text, expected):
    s = parse_query_spec(text)
    assert (s.source, s.start, s.end, s.seconds) == expected
    assert parse_query_spec(s.text()) == s


@pytest.mark.parametrize("text", ["a.amc:40-10", "a.amc:1s-30", "a.amc:1.5-3"])
def test_bad_query_specs(text):
    with pytest.raises(ConfigError):
        parse_query_spec(text)


def test_query_range_checked_against_clip():
    with pytest.raises(ConfigError):
        parse_query_spec("a:10-50").frames(30.0, 40)
    assert parse_query_spec("a:1s-2s").frames(30.0, 90) == (30, 60)


def test_search_pipeline_and_cli_end_to_end(tmp_path, capsys):
    from conftest import EXAMPLES_DATA, REPO

    if not (EXAMPLES_DATA / "cmu").is_dir():
        pytest.skip("examples/data/cmu is absent")
    from mocapflow.framework.cli import main
    from mocapflow.framework.datasets import read_datasets
    from mocapflow.framework.runner import run_pipeline

    ws = tmp_path / "ws"
    # the queries are cut from database clips: let them find themselves (exclude_self: off)
    off = ["matches.exclude_self=off", "exact.exclude_self=off"]
    run_pipeline(REPO / "pipelines" / "search.yaml", workspace=ws, overrides=off, echo=lambda s: None)
    ds = read_datasets(ws)
    lng, exact = ds["matches"].table().to_pylist(), ds["exact"].table().to_pylist()
    # every query is found in its own clip at cost 0, by both matchers
    for rows in (lng, exact):
        best = [r for r in rows if r["rank"] == 1]
        assert len(best) == 3 and all(r["cost"] == pytest.approx(0.0, abs=1e-6) for r in best)
    # the LNG's ranked costs agree with exact subsequence DTW where both report the segment
    key = lambda r: (r["query_id"], r["clip_id"], r["start_frame"], r["end_frame"])  # noqa: E731 - a one-line helper local to this function
    ref = {key(r): r["cost"] for r in exact}
    common = [(r["cost"], ref[key(r)]) for r in lng if key(r) in ref]
    assert len(common) >= 9 and all(a == pytest.approx(b, rel=1e-4, abs=1e-4) for a, b in common)
    assert sorted(p.name for p in (ws / "matches" / "plots").iterdir())[:2] == ["q0_m1.png", "q0_m2.png"]
    logical = ds["logical"].table()
    assert logical.num_rows >= 1 and set(logical["round"].to_pylist()) <= {1, 2, 3}
    assert all(c <= 0.2 for c in logical["cost_normalized"].to_pylist())
    capsys.readouterr()
    assert main(["--no-entry-points", "search", "--db", str(ws), "--query", "02_01:0-40", "--count", "3"]) == 0
    out = capsys.readouterr().out
    assert "its own span excluded" in out.splitlines()[0] and len(out.splitlines()) == 5
    query_file = EXAMPLES_DATA / "cmu" / "16" / "16_15.amc"
    args = ["--no-entry-points", "search", "--db", str(ws), "--query", f"{query_file}:1s-3s", "--count", "2"]
    assert main([*args, "--exclude-self", "off"]) == 0
    best = capsys.readouterr().out.splitlines()[2].split()
    # read, resampled to 30 Hz, found where it came from, in the take's frames (120 Hz) and seconds
    assert best[:7] == ["1", "16_15", "120", "120", "360", "1.00", "2.00"]
    assert main(args) == 0  # by default a query file that is a database take does not find itself
    out = capsys.readouterr().out.splitlines()
    assert "its own span excluded" in out[0] and out[2].split()[:5] != best[:5]
    assert main(["--no-entry-points", "search", "--db", str(ws), "--query", "nonexistent.amc"]) != 0
    # the default (matchers.search) is subsequence DTW's answer; --out into a folder that does not exist creates it
    capsys.readouterr()
    out = tmp_path / "new" / "folder" / "m.csv"
    args = ["--no-entry-points", "search", "--db", str(ws), "--query", "02_01:10-50", "--count", "4"]
    assert main(args + ["--out", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "matchers.search" in lines[0]
    exact_out = lines[2:]
    assert main(args + ["--matcher", "sdtw"]) == 0
    assert capsys.readouterr().out.splitlines()[2:] == exact_out and len(exact_out) == 4
    assert main(args + ["--matcher", "lng"]) == 0  # the graph answers (same best match here)
    graph_out = capsys.readouterr().out.splitlines()[2:]
    assert len(graph_out) == 4 and graph_out[0] == exact_out[0]
    assert main(args + ["--paper"]) == 2  # a graph option for the certified search
    assert "paper" in capsys.readouterr().err
    assert out.is_file() and len(out.read_text().splitlines()) == 5 and not list(out.parent.glob(".m.csv*"))
    assert (
        main(
            args
            + [
                "--matcher",
                "lng",
                "--paper",
                "--min-span",
                "1.0",
                "--rank-by",
                "normalized",
                "--out",
                str(out.with_suffix(".parquet")),
            ]
        )
        == 0
    )
    import pyarrow.parquet as pq

    t = pq.read_table(out.with_suffix(".parquet"))
    assert all(e - s >= 40 for s, e in zip(t["start_frame"].to_pylist(), t["end_frame"].to_pylist(), strict=True))
    # the global --block reaches the commands: blocking the similarity package removes `search`
    with pytest.raises(SystemExit) as exit_:
        main(
            [
                "--no-entry-points",
                "--block",
                "mocapflow.plugins.similarity.plugin",
                "search",
                "--db",
                str(ws),
                "--query",
                "02_01:0-40",
            ]
        )
    assert exit_.value.code == 2 and "invalid choice: 'search'" in capsys.readouterr().err
    assert main(["--no-entry-points", "search", "--db", str(tmp_path / "missing"), "--query", "02_01:0-40"]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_query_files_enter_the_fingerprint(tmp_path):
    f = tmp_path / "walk.amc"
    f.write_text("x")
    m = CertifiedSearch(queries=["walk.amc:0-10", "some_clip:0-5"])
    before = m.source_fingerprint(tmp_path)
    assert before and CertifiedSearch(queries=["some_clip"]).source_fingerprint(tmp_path) == ""
    f.write_text("xy")
    assert m.source_fingerprint(tmp_path) != before
