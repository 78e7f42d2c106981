"""matchers.relational mode auto: flicker removal, frame bits from the index, and queries by
example without a feature list (HDM05 where available)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mocapflow.plugins.relational.auto import auto_hits, auto_template, runs, smooth_runs
from mocapflow.plugins.relational.inverted import InvertedIndex
from mocapflow.plugins.relational.template_model import frame_codes

HDM05 = Path(__file__).resolve().parents[4] / "shared" / "data" / "hdm05" / "amc"


def test_smooth_runs_absorbs_short_inner_runs_shortest_first():
    x = np.array([0] * 6 + [1] * 2 + [0] * 5 + [1] * 8 + [0] + [1] * 6 + [0] * 6, bool)
    y = smooth_runs(x, 3)
    vals, lens = runs(y)
    assert vals.tolist() == [False, True, False] and lens.tolist() == [13, 15, 6]
    assert smooth_runs(x, 1).tolist() == x.tolist()  # nothing is shorter than one frame


def test_smooth_runs_edges_and_constants():
    assert smooth_runs(np.array([1, 0, 0, 0, 0, 0], bool), 3).tolist() == [False] * 6  # flicker at the cut
    assert smooth_runs(np.zeros(5, bool), 3).tolist() == [False] * 5
    assert smooth_runs(np.zeros(0, bool), 3).tolist() == []


def test_frame_bits_from_the_index_are_the_features():
    rng = np.random.default_rng(0)
    bits = rng.random((200, 31)) < 0.2
    clip = np.repeat([4, 7, 9], [50, 100, 50]).astype(np.int32)
    idx = InvertedIndex().build(bits, clip)
    np.testing.assert_array_equal(idx.frame_bits(), bits)


def test_auto_template_retrieves_the_example_pattern():
    rng = np.random.default_rng(1)
    q = np.zeros((40, 31), np.float32)
    q[10:25, 3] = 1
    q[12, 3] = 0  # flicker inside the on phase
    db = (rng.random((400, 31)) < 0.02).astype(np.float32)
    db[100:150, 3] = 0
    db[110:135, 3] = 1  # a slower performance of the same progression
    offsets = np.array([0, 200, 400])
    bg = db.mean(axis=0)
    t = auto_template(q, bg, min_run=3)
    assert 3 in t.columns
    s, e, c, cut = auto_hits(t, frame_codes(db), offsets)
    assert len(s) and c[0] <= cut
    assert s[0] <= 110 and e[0] >= 135  # the best hit is the slower performance


@pytest.mark.skipif(not HDM05.is_dir(), reason="needs the HDM05 cuts in ../shared/data/hdm05")
def test_auto_query_by_example_on_hdm05(tmp_path):
    import pyarrow.parquet as pq

    from mocapflow.framework.runner import run_pipeline

    kicks = sorted(str(p) for p in HDM05.glob("*/*kickLFront*.amc"))
    squats = sorted(str(p) for p in HDM05.glob("*/*squat*.amc"))
    files = kicks[:4] + squats[:4]
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
      queries: [{{clip: {Path(kicks[0]).stem}}}, {{clip: {Path(squats[0]).stem}, examples: [{Path(squats[2]).stem}]}}]
""")
    run_pipeline(yaml)
    hits = pq.read_table(tmp_path / "ws" / "hits" / "data.parquet").to_pylist()
    clips = {r["clip_id"]: r["name"] for r in pq.read_table(tmp_path / "ws" / "motions" / "clips.parquet").to_pylist()}
    for qid, word in ((0, "kick"), (1, "squat")):
        mine = sorted((h for h in hits if h["query_id"] == qid), key=lambda h: h["rank"])
        assert mine and all(h["mode"] == "auto" and h["features"] for h in mine)
        assert all(word in clips[h["clip_id"]] for h in mine[:3])
    assert (
        "L4" in next(h for h in hits if h["query_id"] == 0)["features"]
    )  # left foot raised: HDM05 kicks are left kicks


def test_relative_cost_cut_separates_the_few_cheap_clips_from_the_bulk():
    from mocapflow.plugins.relational.auto import relative_cost_cut

    # 6 clips hold the motion (cheap), 60 do not (the bulk), one cannot fit a path at all (inf)
    rng = np.random.default_rng(0)
    per_clip = np.r_[[0.02, 0.03, 0.04, 0.05, 0.05, 0.06], rng.uniform(0.3, 0.6, 60), np.inf]
    cut = relative_cost_cut(per_clip)
    assert 0.06 < cut < 0.3  # every cheap clip in, every typical one out
    # a looser relative cut admits more, never fewer clips
    assert relative_cost_cut(per_clip, 2.0) > cut
    assert relative_cost_cut(np.array([np.inf]), 1.1) == 0.0  # nothing fits: nothing is a hit


@pytest.mark.parametrize("seed", range(3))
def test_weighted_cost_table_matches_naive_local_cost(seed):
    from naive import templates as naive_templates

    from mocapflow.plugins.relational.template_model import cost_table, frame_codes

    rng = np.random.default_rng(seed)
    q = rng.choice([0.0, 0.5, 1.0], size=(5, 31)).astype(np.float32)
    w = rng.random((5, 31)) * 3
    bits = rng.random((20, 31)) < 0.3
    codes = frame_codes(bits)
    table = cost_table(q, w)
    lo, up, mid = codes & 2047, 2048 + ((codes >> 11) & 4095), 6144 + ((codes >> 23) & 255)
    got = (table[lo] + table[up] + table[mid]).T.astype(np.float64)
    np.testing.assert_allclose(got, naive_templates.local_cost(q, bits, w), atol=1e-5)


def test_surprise_weights_and_auto_template_weighting():
    from mocapflow.plugins.relational.auto import auto_template, surprise_weights

    bg = np.full(31, 0.5)
    bg[0], bg[1] = 0.125, 0.875
    q = np.zeros((2, 31))
    q[0, 0] = q[1, 1] = 1.0
    w = surprise_weights(q, bg, 1.0)
    assert w[0, 0] == pytest.approx(3.0)  # a rare 'on': -log2(1/8)
    assert w[1, 1] == pytest.approx(-np.log2(0.875))  # a common 'on' costs little
    assert w[0, 1] == pytest.approx(3.0)  # 'off' where the database is mostly on
    assert np.all(surprise_weights(q, bg, 0.0) == 1.0)
    bits = np.zeros((12, 31))
    bits[4:8, 0] = 1
    t = auto_template(bits, bg, None, 2)
    assert t.weights is not None and t.weights.shape == (12, 31) and len(t.columns) == 31
    assert auto_template(bits, bg, None, 2, weighting=0.0).weights is None


def _runs_motion(rng, n):  # runs of 5 frames: no flicker for min_run 4
    return np.repeat(rng.random((n, 31)) < 0.3, 5, axis=0)


def test_mutual_check_auto_keeps_hits_inside_a_long_take():
    """auto_mutual auto: a clip of at most ratio x the query is checked whole (the short
    motion containing the query is rejected: as a query it does not find the hop); inside a
    long take (many motions) the hit is not checked and kept, where the whole-clip check
    rejects it."""
    from mocapflow.plugins.relational.auto import mutual_check

    rng = np.random.default_rng(0)
    hop = _runs_motion(rng, 6)  # 30 frames
    medium = np.concatenate([_runs_motion(rng, 3), hop, _runs_motion(rng, 3)])  # 60 frames <= 3 x 30
    take = np.concatenate([_runs_motion(rng, 8) for _ in range(20)] + [hop] + [_runs_motion(rng, 8) for _ in range(20)])
    clips = [hop.copy(), medium, take] + [_runs_motion(rng, 8) for _ in range(8)]
    db = np.concatenate(clips).astype(np.uint8)
    offsets = np.concatenate([[0], np.cumsum([len(c) for c in clips])]).astype(np.int64)
    codes, bg = frame_codes(db), db.mean(axis=0)
    in_medium = offsets[1] + 15
    in_take = offsets[2] + 20 * 40
    s = np.array([0, in_medium, in_take])
    e = s + len(hop)
    keep, checked = mutual_check(hop, s, e, db, codes, offsets, bg, "auto", ratio=3.0)
    assert checked.tolist() == [True, True, False] and keep.tolist() == [True, False, True]
    keep_clip, checked_clip = mutual_check(hop, s, e, db, codes, offsets, bg, "clip")
    assert checked_clip.all() and keep_clip.tolist() == [True, False, False]  # clip rejects the take's hop


def _hdm05_bits(files):
    from mocapflow.framework.database import MotionDatabase
    from mocapflow.framework.normalize import resample
    from mocapflow.plugins.formats.asf_amc import read_amc
    from mocapflow.plugins.relational.body import body_measures
    from mocapflow.plugins.relational.features import relational_features

    db = MotionDatabase([resample(read_amc(f), 30.0) for f in files])
    per = [body_measures(m.skeleton) for m in db.motions]
    meas = {
        k: np.repeat([p[k] for p in per], np.diff(db.offsets)).astype(np.float32)
        for k in ("humerus_length", "shoulder_width", "hip_width")
    }
    return relational_features(db.canonical_positions(), db.fps, meas, None, db.offsets), np.asarray(
        db.offsets, np.int64
    )


@pytest.mark.skipif(not HDM05.is_dir(), reason="needs the HDM05 cuts in ../shared/data/hdm05")
def test_default_mutual_check_keeps_true_hits_in_a_long_take_of_hdm05_cuts():
    """A long take made by concatenating one actor's HDM05 cuts (one of each class), next to
    the other two actors' cuts as separate clips (as in the benchmark's database of 66 cuts,
    which the relative cut needs): with the default auto_mutual (auto) every true hit that
    the search without the check finds inside the take is kept; the whole-clip check
    (auto_mutual: clip) rejects them all."""
    from mocapflow.plugins.relational.auto import auto_dtw_hits

    classes = sorted({p.stem.split("_")[2] for p in HDM05.glob("dg/*.amc")})
    take_files = [sorted(HDM05.glob(f"dg/*_{c}_*.amc"))[0] for c in classes]
    cut_files = [f for a in ("bd", "bk") for c in classes for f in sorted(HDM05.glob(f"{a}/*_{c}_*.amc"))]
    if len(classes) < 8 or len(cut_files) < 4 * len(classes):
        pytest.skip("HDM05 cuts of actors bd, bk and dg not all present")
    bits, off = _hdm05_bits(take_files + cut_files)
    n_take = len(take_files)
    offsets = np.concatenate([[0], off[n_take:]])  # the dg cuts become one clip (a take)
    true_span = np.stack([off[:n_take], off[1 : n_take + 1]], axis=1)
    codes, bg = frame_codes(bits), bits.mean(axis=0)
    found = {m: set() for m in ("off", "auto", "clip")}
    for i in range(len(classes)):
        q = n_take + 2 * i  # the bd cut of class i
        qb = bits[off[q] : off[q + 1]]
        t = auto_template(qb, bg)
        for mode in found:
            s, e, _ = auto_dtw_hits(t, qb, bits, codes, offsets, bg, mode)
            if any(a < true_span[i, 1] and b > true_span[i, 0] for a, b in zip(s, e, strict=True)):
                found[mode].add(i)
    assert len(found["off"]) >= len(classes) // 2  # the test is not vacuous
    assert found["off"] <= found["auto"]  # no true hit in the take is rejected
    assert not found["clip"]  # the whole-take check would reject them


def test_reverse_costs_cut_out_the_hit_and_sample_the_database():
    """reverse_costs: the per-range costs are the clips' least costs with the reverse frames
    cut out of their clip (checked against clip_min_costs on split offsets); with max_clips
    a sample of the other clips, whose costs are a subset of the full ones."""
    from mocapflow.plugins.relational.auto import auto_template, reverse_costs
    from mocapflow.plugins.relational.template_model import clip_min_costs

    rng = np.random.default_rng(3)
    clips = [_runs_motion(rng, int(k)) for k in rng.integers(4, 12, size=30)]
    db = np.concatenate(clips).astype(np.uint8)
    offsets = np.concatenate([[0], np.cumsum([len(c) for c in clips])]).astype(np.int64)
    codes, bg = frame_codes(db), db.mean(axis=0)
    q = clips[0]
    lo, hi = int(offsets[5] + 5), int(offsets[5] + 20)  # a window inside clip 5
    own, per = reverse_costs(db[lo:hi], lo, hi, frame_codes(q), codes, offsets, bg, max_clips=None)
    t = auto_template(db[lo:hi], bg)
    split = np.unique(np.concatenate([offsets, [lo, hi]]))
    ref = clip_min_costs(codes, split, t.table())
    ref = np.delete(ref, np.searchsorted(split, lo))  # the window itself is left out
    np.testing.assert_allclose(np.sort(per), np.sort(ref))
    assert own == pytest.approx(clip_min_costs(frame_codes(q), np.array([0, len(q)]), t.table())[0])
    own_s, per_s = reverse_costs(db[lo:hi], lo, hi, frame_codes(q), codes, offsets, bg, max_clips=10)
    assert own_s == own and len(per_s) == 10 + 2 and np.isin(per_s, per).all()
