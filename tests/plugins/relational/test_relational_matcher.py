"""matchers.relational: queries by example, several indexes, scene descriptions, ranking, DTW refinement."""

from __future__ import annotations

import glob

import numpy as np
import pytest
from conftest import corpus_path
from naive import relational as naive

from mocapflow.framework.errors import ConfigError
from mocapflow.plugins.relational._match_kernels import banded_dtw
from mocapflow.plugins.relational.feature_table import FEATURE_IDS, feature_column
from mocapflow.plugins.relational.inverted import InvertedIndex
from mocapflow.plugins.relational.matcher import dtw_band
from mocapflow.plugins.relational.queries import combine, example_query, scene_query
from mocapflow.plugins.relational.segmentation import pack_codes, segment_codes

RNG = np.random.default_rng(11)


def runs_db(n_frames=600, n_clips=4, p=0.25):
    """Random piecewise-constant 31-feature bits in several clips."""
    change = RNG.random((n_frames, 31)) < 0.08
    bits = np.cumsum(change, axis=0) % 2 == 1
    bits &= RNG.random(31) < 0.9  # a few features always off
    clip_id = np.sort(RNG.integers(0, n_clips, n_frames))
    return bits, clip_id


@pytest.mark.parametrize("mode", ["adaptive", "fuzzy", "mismatch"])
def test_query_by_example_matches_naive_on_projected_database(mode):
    bits, clip_id = runs_db()
    index = InvertedIndex().build(bits, clip_id)
    cols = [feature_column(f) for f in ("L3", "L4", "L7")]
    offsets = index.sets["lower"].clip_offsets
    # the database segmentation restricted to the selected features
    coarse = segment_codes(pack_codes(bits, cols), offsets)
    full = segment_codes(pack_codes(bits, list(range(11))), offsets)
    for _ in range(5):
        k = int(RNG.integers(0, len(coarse) - 3))
        if coarse.clip[k] != coarse.clip[k + 2]:
            continue
        q = bits[coarse.start[k] : coarse.end[k + 2]]
        hits = example_query(index, q, cols, mode, mismatches=1)
        qcodes = coarse.code[k : k + 3].tolist()
        if mode == "adaptive":
            want = naive.exact_hits(coarse.code.tolist(), coarse.clip.tolist(), qcodes)
            assert sorted(hits.start.tolist()) == sorted(coarse.start[want].tolist())
            assert coarse.start[k] in hits.start
        elif mode == "mismatch":
            sets = [{c} for c in qcodes]
            want = naive.mismatch_hits(coarse.code.tolist(), coarse.clip.tolist(), sets, 1)
            assert sorted(hits.start.tolist()) == sorted(coarse.start[[w for w, _ in want]].tolist())
        else:  # fuzzy hits use the database's own (finer) segmentation
            # lower-body columns are the set's own bit positions
            vals = [sum(((c >> i) & 1) << cols[i] for i in range(3)) for c in qcodes]
            mask = sum(1 << c for c in cols)
            want = naive.fuzzy_hits((full.code & mask).tolist(), full.clip.tolist(), [{v} for v in vals])
            assert sorted(hits.start.tolist()) == sorted(full.start[want].tolist())
        assert (hits.end > hits.start).all()
        assert np.all(hits.cost >= 0)


def test_exact_mode_needs_whole_sets_and_finds_itself():
    bits, clip_id = runs_db()
    index = InvertedIndex().build(bits, clip_id)
    with pytest.raises(ConfigError, match="whole feature sets"):
        example_query(index, bits[:50], [0, 1], "exact")
    s = index.sets["mixed"]
    q = bits[s.seg_start[3] : s.seg_end[6]]
    hits = example_query(index, q, list(range(23, 31)), "exact")
    assert s.seg_start[3] in hits.start and 0.0 in hits.cost


def test_query_spanning_indexes_is_combined():
    bits, clip_id = runs_db()
    index = InvertedIndex().build(bits, clip_id)
    q = bits[100:160]
    lower = example_query(index, q, [2, 3])
    upper = example_query(index, q, [13])
    both = example_query(index, q, [2, 3, 13])
    assert both.sets == "lower+upper"
    assert len(both) <= len(lower) * len(upper)
    # every combined hit overlaps one hit of each part by at least half of the shorter span
    for c, a, b in zip(both.clip, both.start, both.end, strict=True):
        for part in (lower, upper):
            assert np.any((part.clip == c) & (part.start >= a) & (part.end <= b))
    again = combine(lower, upper, 0.5)
    np.testing.assert_array_equal(again.start, both.start)


def test_scene_description_with_cooccurrence():
    # clip 0: foot raised while the knee is bent; clip 1: raised and bent one after the other
    t = 60
    bits = np.zeros((2 * t, 31), bool)
    raised, bent = feature_column("lfoot_raised"), feature_column("lknee_bent")
    bits[10:25, raised] = True
    bits[15:30, bent] = True
    bits[t + 10 : t + 20, raised] = True
    bits[t + 30 : t + 40, bent] = True
    index = InvertedIndex().build(bits, np.repeat([0, 1], t))
    progs = [[{"lfoot_raised": 0}, {"lfoot_raised": 1}, {"lfoot_raised": 0}], [{"L8": 0}, {"L8": 1}, {"L8": 0}]]
    free = scene_query(index, progs)
    assert set(free.clip.tolist()) == {0, 1}
    hits = scene_query(index, progs, [(0, 1, 1, 1)])
    assert hits.clip.tolist() == [0]
    with pytest.raises(ConfigError, match="one set"):
        scene_query(index, [[{"L3": 1, "U3": 1}]])
    with pytest.raises(ConfigError, match="differ"):
        scene_query(index, [[{"L3": 1}, {"L4": 1}]])


def test_banded_dtw_matches_naive_and_path_is_valid():
    a, b = RNG.normal(size=(17, 4)), RNG.normal(size=(23, 4))
    full_lo, full_hi = np.zeros(17, np.int64), np.full(17, 23, np.int64)
    cost, path, cells = banded_dtw(a, b, full_lo, full_hi)
    assert cost == pytest.approx(naive.dtw(a, b))
    assert cells == 17 * 23
    assert tuple(path[0]) == (0, 0) and tuple(path[-1]) == (16, 22)
    assert (np.diff(path, axis=0) >= 0).all() and (np.diff(path, axis=0).sum(1) >= 1).all()
    # restricted to matched segments plus a margin
    ql = np.array([[0, 5], [5, 12], [12, 17]])
    dl = np.array([[0, 9], [9, 14], [14, 23]])
    lo, hi = dtw_band(ql, dl, margin=2)
    cost_b, path_b, cells_b = banded_dtw(a, b, lo, hi)
    assert cost_b == pytest.approx(naive.dtw(a, b, lo, hi))
    assert cells_b < cells and cost_b >= cost - 1e-9
    assert all(lo[i] <= j < hi[i] for i, j in path_b)
    # one-frame sequences
    c1, p1, _ = banded_dtw(a[:1], b[:1], np.zeros(1, np.int64), np.ones(1, np.int64))
    assert c1 == pytest.approx(np.linalg.norm(a[0] - b[0])) and p1.tolist() == [[0, 0]]


def test_retrieval_pipeline_end_to_end(tmp_path):
    import pyarrow.parquet as pq

    from mocapflow.framework.runner import run_pipeline

    root = corpus_path("hdm05", "amc")
    files = sorted(glob.glob(str(root / "bd" / "*kick*"))) + sorted(glob.glob(str(root / "bd" / "*squat*")))
    yaml = tmp_path / "r.yaml"
    yaml.write_text(f"""name: r
workspace: ws
steps:
  motions: {{uses: formats.load, with: {{paths: {files!r}, fps: 30}}}}
  relational: {{uses: features.relational, input: motions}}
  inverted: {{uses: indexes.inverted, input: relational}}
  hits:
    uses: matchers.relational
    inputs: {{database: inverted, query: relational, motions: motions}}
    with:
      mode: adaptive
      refine: true
      queries: [{{clip: {Path_stem(files[0])}, features: [L3, L4, L7, L8]}}]
      scenes: [{{progressions: [[{{lfoot_raised: 0}}, {{lfoot_raised: 1}}, {{lfoot_raised: 0}}]]}}]
""")
    run_pipeline(yaml)
    hits = pq.read_table(tmp_path / "ws" / "hits" / "data.parquet").to_pylist()
    clips = {r["clip_id"]: r["name"] for r in pq.read_table(tmp_path / "ws" / "motions" / "clips.parquet").to_pylist()}
    q0 = [h for h in hits if h["query_id"] == 0]
    assert q0[0]["rank"] == 1 and clips[q0[0]["clip_id"]] == Path_stem(files[0]) and q0[0]["cost"] == 0.0
    assert all("kick" in clips[h["clip_id"]] for h in q0)
    assert q0[0]["path_analysis"][0] == [q0[0]["start_frame_analysis"], q0[0]["start_frame_analysis"]]
    assert {clips[h["clip_id"]] for h in hits if h["query_id"] == 1} == {Path_stem(f) for f in files[:2]}
    segs = pq.read_table(tmp_path / "ws" / "inverted" / "data.parquet")
    assert set(segs.column_names) >= {"feature_set", "clip_id", "start_frame", "end_frame", "code"}
    assert list(FEATURE_IDS[:2]) == ["L1", "L2"]


def Path_stem(p: str) -> str:
    from pathlib import Path

    return Path(p).stem
