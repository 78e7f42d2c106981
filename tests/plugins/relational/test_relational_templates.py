"""Motion templates (matchers.template, analyses.classify): kernels against tests/naive/templates.py,
learning, don't-care cells, retrieval of planted occurrences, storage, and the pipeline on HDM05."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from naive import templates as naive

from mocapflow.plugins.relational._template_kernels import dtw_path
from mocapflow.plugins.relational.classify import decide
from mocapflow.plugins.relational.template_model import (
    MotionTemplate,
    cost_table,
    fit_class_template,
    fit_template,
    frame_codes,
    load_templates,
    save_templates,
    template_costs,
    template_hits,
)

HDM05 = Path(__file__).resolve().parents[4] / "shared" / "data" / "hdm05" / "amc"


def _table_cost(table, codes):
    """c[k, j] from the lookup table, straight from its definition."""
    lo, up, mid = codes & 2047, 2048 + ((codes >> 11) & 4095), 6144 + ((codes >> 23) & 255)
    return (table[lo] + table[up] + table[mid]).T.astype(np.float64)


@pytest.mark.parametrize("seed", range(4))
def test_dtw_path_matches_naive(seed):
    rng = np.random.default_rng(seed)
    a = rng.random((int(rng.integers(1, 9)), 5))
    b = rng.random((int(rng.integers(1, 9)), 5))
    cost, path = dtw_path(a, b)
    ncost, npath = naive.dtw_path(a, b)
    assert cost == pytest.approx(ncost)
    np.testing.assert_array_equal(path, npath)


@pytest.mark.parametrize("seed", range(3))
def test_cost_table_matches_naive_local_cost(seed):
    rng = np.random.default_rng(seed)
    q = rng.choice([0.0, 0.5, 1.0], size=(6, 31)).astype(np.float32)
    q[2] = 0.5  # a frame that cares about nothing costs nothing
    bits = rng.random((40, 31)) < 0.3
    got = _table_cost(cost_table(q), frame_codes(bits))
    np.testing.assert_allclose(got, naive.local_cost(q, bits), atol=1e-6)
    assert np.all(got[2] == 0)


@pytest.mark.parametrize("seed", range(6))
def test_subsequence_dtw_matches_naive(seed):
    rng = np.random.default_rng(seed)
    k = int(rng.integers(1, 7))
    lengths = rng.integers(1, 15, size=int(rng.integers(1, 5)))  # one-frame clips included
    offsets = np.concatenate([[0], np.cumsum(lengths)])
    n = int(offsets[-1])
    codes = rng.integers(0, 1 << 31, size=n, dtype=np.int64)
    codes[3:6] = codes[2]  # runs of equal codes (the kernel reuses their cost column)
    table = rng.random((6400, k)).astype(np.float32)  # continuous costs: no ties
    cost, start = template_costs(codes, table, np.stack([offsets[:-1], offsets[1:]], 1))
    clip_of = np.repeat(np.arange(len(lengths)), lengths)
    ncost, nstart = naive.subsequence_dtw(_table_cost(table, codes), clip_of)
    np.testing.assert_allclose(cost, ncost, rtol=1e-5)
    fin = np.isfinite(ncost)
    np.testing.assert_array_equal(start[fin], nstart[fin])
    assert np.all(clip_of[start[fin]] == clip_of[fin])  # paths never cross a clip boundary


def test_subsequence_dtw_binary_template_matches_naive_costs():
    rng = np.random.default_rng(7)
    q = rng.choice([0.0, 0.5, 1.0], size=(5, 31)).astype(np.float32)
    bits = rng.random((60, 31)) < 0.5
    offsets = np.array([0, 25, 60])
    cost, _ = template_costs(frame_codes(bits), cost_table(q), np.stack([offsets[:-1], offsets[1:]], 1))
    ncost, _ = naive.subsequence_dtw(naive.local_cost(q, bits), np.repeat([0, 1], [25, 35]))
    np.testing.assert_allclose(cost, ncost, atol=1e-6)


def _pattern(n_frames: int, phase: tuple[float, float]) -> np.ndarray:
    """A 31-feature clip: feature 3 on during ``phase`` (fractions of the clip), 20 always on."""
    x = np.zeros((n_frames, 31), np.float32)
    t = np.arange(n_frames) / n_frames
    x[(t >= phase[0]) & (t < phase[1]), 3] = 1
    x[:, 20] = 1
    return x


def test_fit_template_from_warped_copies_is_the_pattern():
    ex = [_pattern(40, (0.25, 0.5)), _pattern(60, (0.25, 0.5)), _pattern(50, (0.25, 0.5))]
    t = fit_template("a", ex, delta=0.2)
    q = t.quantized()
    k = t.n_frames
    assert k in (40, 50, 60)  # one example's time axis (the medoid; all fit perfectly here)
    assert set(np.unique(q)) <= {0.0, 1.0}  # the examples agree everywhere: no don't care
    on = np.flatnonzero(q[:, 3] == 1)
    assert 0.2 * k <= on[0] <= 0.3 * k and 0.45 * k <= on[-1] + 1 <= 0.55 * k
    assert np.all(q[:, 20] == 1) and np.all(q[:, 0] == 0)


def test_disagreeing_examples_give_dont_care():
    ex = [_pattern(40, (0.25, 0.5)) for _ in range(4)]
    for i in (0, 1):
        ex[i][:, 7] = 1  # half the examples have feature 7 on throughout
    t = fit_template("a", ex, delta=0.2)
    assert np.all(t.quantized()[:, 7] == 0.5)
    assert t.dont_care_fraction() == pytest.approx(1 / 31)


def test_template_hits_find_planted_occurrences():
    rng = np.random.default_rng(3)
    ex = [_pattern(n, (0.3, 0.6)) for n in (30, 36, 42)]
    t = fit_class_template("a", ex, features="all")
    noise = (rng.random((300, 31)) < 0.02).astype(np.float32)
    db = noise.copy()
    db[50:85] = _pattern(35, (0.3, 0.6))
    db[200:245] = _pattern(45, (0.3, 0.6))
    cost, start = template_costs(frame_codes(db), t.table(), np.array([[0, 300]]))
    s, e, c = template_hits(cost, start, t.threshold)
    found = sorted(zip(s.tolist(), e.tolist(), strict=True))
    assert len(found) == 2
    for (a, b), (ta, tb) in zip(found, [(50, 85), (200, 245)], strict=False):
        # the constant lead-in may be compressed (up to 2x): the span overlaps the planted one
        assert (min(b, tb) - max(a, ta)) / (max(b, tb) - min(a, ta)) >= 0.7
    assert np.all(c <= t.threshold)


def test_key_features_drop_background_and_keep_progressions():
    ex = [_pattern(n, (0.3, 0.6)) for n in (30, 36, 42)]
    bg = np.full(31, 0.0)
    bg[20] = 1.0  # feature 20 is on in every motion of the database: not characteristic
    t = fit_class_template("a", ex, background=bg, features="key")
    assert 3 in t.columns and 20 not in t.columns and 0 not in t.columns


def test_templates_save_load_roundtrip(tmp_path):
    t = fit_class_template("kick", [_pattern(n, (0.3, 0.6)) for n in (30, 36)])
    save_templates([t], tmp_path, {"label_pattern": "x"})
    (u,), meta = load_templates(tmp_path)
    assert meta == {"label_pattern": "x"} and isinstance(u, MotionTemplate)
    np.testing.assert_array_equal(u.mean, t.mean)
    np.testing.assert_array_equal(u.columns, t.columns)
    assert (u.label, u.threshold, u.delta, u.n_examples) == (t.label, t.threshold, t.delta, t.n_examples)


def test_decide_confidence():
    costs = np.array([[0.1, 0.2, 0.4], [0.3, np.inf, np.inf], [np.inf, np.inf, np.inf]])
    best, c1, second, conf = decide(costs)
    assert best.tolist() == [0, -1, -1] and second[0] == 1 and second[1] == -1
    # no runner-up: unknown with confidence 0, never 1.0 by default
    assert conf[0] == pytest.approx(0.5) and conf[1] == 0.0 and conf[2] == 0.0


def test_a_clip_no_template_can_span_is_scored_at_a_penalty():
    from mocapflow.plugins.relational.classify import classify_clips, span_fraction

    a = fit_class_template("a", [_pattern(20, (0.2, 0.5)), _pattern(22, (0.2, 0.5))], features="all")
    other = [_pattern(n, (0.6, 0.9)) for n in (80, 84)]
    for x in other:  # another motion: half the features the other way round
        x[:, :16] = 1 - x[:, :16]
    b = fit_class_template("b", other, features="all")
    slow = _pattern(60, (0.2, 0.5))  # a performed three times slower: template a (K about 20) cannot span it
    f = span_fraction(np.array([a.n_frames, b.n_frames]), np.array([60]))
    assert f[0, 0] < 1.0 and f[0, 1] == 1.0
    costs = classify_clips([a, b], slow > 0.5, np.array([0, 60]), penalty=0.2)
    best, _, second, conf = decide(costs)
    assert np.all(np.isfinite(costs)) and second[0] >= 0 and conf[0] < 1.0
    assert best[0] == 0  # the best-fitting template wins at the penalty, not the only one long enough


@pytest.mark.skipif(not HDM05.is_dir(), reason="needs the HDM05 cuts in ../shared/data/hdm05")
def test_templates_pipeline_on_hdm05(tmp_path):
    from mocapflow.framework import get_plugin_manager
    from mocapflow.framework.catalog import Catalog
    from mocapflow.framework.runner import run_pipeline

    path = Path(__file__).resolve().parents[3] / "pipelines" / "templates.yaml"
    run_pipeline(path, workspace=tmp_path, pm=get_plugin_manager(entry_points=False))
    with Catalog(tmp_path) as cat:
        assert cat.query("SELECT count(*) AS n FROM templates_templates").column("n")[0].as_py() == 11
        acc = cat.query("SELECT avg(correct::INT) AS a FROM classify WHERE held_out").column("a")[0].as_py()
        assert acc >= 0.9  # the held-out actor dg (docs/templates.md)
        # the reported list (cutoff: rivals) on the held-out actor dg's cuts: precise, and most found by their class
        dg = cat.query(
            "SELECT h.label, c.name FROM templates h JOIN clips c USING (clip_id) WHERE c.name LIKE 'HDM_dg_%'"
        ).to_pylist()
        right = [r for r in dg if r["label"] in r["name"]]
        assert len(right) >= 0.8 * len(dg) and len({r["name"] for r in right}) >= 18
        top = cat.query(
            "SELECT h.label, c.name FROM templates h JOIN clips c USING (clip_id) WHERE h.rank = 1"
        ).to_pylist()
        assert all(r["label"] in r["name"] for r in top)
    assert len(list((tmp_path / "templates").glob("template_*.png"))) == 11


@pytest.mark.parametrize("seed", range(5))
def test_hit_selection_matches_naive(seed):
    rng = np.random.default_rng(seed)
    n = 300
    cost = np.round(rng.random(n), 2)  # ties included
    cost[rng.random(n) < 0.1] = np.inf
    start = np.maximum(np.arange(n) - rng.integers(0, 40, n), 0)
    for thr, gap in ((0.3, 0.5), (0.6, 0.0), (1.0, 0.9)):
        got = template_hits(cost, start, thr, gap)
        want = naive.template_hits(cost, start, thr, gap)
        for g, w in zip(got, want, strict=True):
            np.testing.assert_array_equal(g, w)


def _admissible_on(templates, bits, offsets):
    """Every template's per-clip bound (the search's pre-filter) <= K x the DP's least end cost of the clip."""
    from mocapflow.plugins.relational._template_kernels import _remaining_bound
    from mocapflow.plugins.relational.template_coarse import CoarseCodes, coarse_template, template_step
    from mocapflow.plugins.relational.template_cutoff import _all_columns

    cc = CoarseCodes(frame_codes(bits), offsets)
    checked = 0
    for t0 in templates:
        for t in (t0, _all_columns(t0)):
            for step in sorted({1, template_step(t, "auto")}):
                codes, off, _ = cc.get(step)
                ct = coarse_template(t, step)
                table = ct.table()
                cost, _ = template_costs(codes, table, np.stack([off[:-1], off[1:]], 1))
                g = np.zeros(ct.n_frames)
                for i in range(len(off) - 1):
                    lb = _remaining_bound(codes, table, off[i], off[i + 1], g)
                    best = cost[off[i] : off[i + 1]].min() * ct.n_frames
                    assert lb <= best + 1e-6, (t.label, step, i, lb, best)
                    checked += 1
    return checked


def test_prefilter_is_a_lower_bound_of_the_dp_on_every_class():
    """The search's only pre-filter (a clip is skipped when its bound exceeds the acceptance
    bound) never exceeds the DP's cost: synthetic classes here, HDM05 in the slow test."""
    rng = np.random.default_rng(5)
    clips, labels = [], []
    for c in range(3):
        pattern = np.repeat(rng.random((10, 31)) < 0.25, 4, axis=0)
        for _ in range(4):
            n = int(len(pattern) * rng.uniform(0.7, 1.4))
            x = pattern[np.minimum((np.arange(n) * len(pattern) / n).astype(int), len(pattern) - 1)]
            clips.append((x ^ (rng.random(x.shape) < 0.03)).astype(np.float32))
            labels.append(f"c{c}")
    offsets = np.concatenate([[0], np.cumsum([len(x) for x in clips])]).astype(np.int64)
    bits = np.concatenate(clips) > 0.5
    from mocapflow.plugins.relational.template import fit_templates

    temps = fit_templates(bits, offsets, labels, np.ones(len(clips), bool))
    assert _admissible_on(temps, bits, offsets) > 0


@pytest.mark.slow
@pytest.mark.skipif(not HDM05.is_dir(), reason="needs the HDM05 cuts in ../shared/data/hdm05")
def test_prefilter_is_a_lower_bound_of_the_dp_on_hdm05():
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
    from templates import hdm05_cuts, meta

    from mocapflow.plugins.relational.template import fit_templates

    bits, offsets, names, _ = hdm05_cuts(30.0)
    cls, act = meta(names)
    for held in sorted(set(act)):  # the templates of every leave-one-actor-out fold, every class
        temps = fit_templates(bits, offsets, list(cls), act != held, list(act))
        assert _admissible_on(temps, bits, offsets) > 0


def test_index_input_is_deprecated_and_changes_nothing():
    from mocapflow.plugins.relational.inverted import InvertedIndex
    from mocapflow.plugins.relational.template import cutoff_hits, search_template

    ex = [_pattern(n, (0.3, 0.6)) for n in (30, 36, 42)]
    t = fit_class_template("a", ex, features="all")
    rng = np.random.default_rng(5)
    db = (rng.random((3000, 31)) < 0.002).astype(np.float32)
    for s0, n in ((100, 35), (900, 45), (2500, 30)):
        db[s0 : s0 + n] = _pattern(n, (0.3, 0.6))
    offsets = np.array([0, 1000, 2000, 3000])
    idx = InvertedIndex().build(db, np.repeat([0, 1, 2], 1000).astype(np.int32))
    full = search_template(t, frame_codes(db), offsets)
    with pytest.warns(DeprecationWarning, match="'index' input is ignored"):
        pre = search_template(t, frame_codes(db), offsets, index=idx)
    for f, p in zip(full, pre, strict=True):
        np.testing.assert_array_equal(f, p)
    assert len(full[0]) == 3
    with pytest.warns(DeprecationWarning):
        cutoff_hits([t], frame_codes(db), offsets, idx)


@pytest.mark.parametrize("seed", range(4))
def test_two_pass_search_matches_the_full_pass(seed):
    from mocapflow.plugins.relational.template_model import search_costs

    rng = np.random.default_rng(seed)
    lengths = rng.integers(1, 80, size=6)
    offsets = np.concatenate([[0], np.cumsum(lengths)])
    codes = rng.integers(0, 1 << 31, size=int(offsets[-1]), dtype=np.int64)
    table = rng.random((6400, int(rng.integers(1, 9)))).astype(np.float32)
    ranges = np.stack([offsets[:-1], offsets[1:]], 1)
    cost, start = template_costs(codes, table, ranges)
    thr = float(np.quantile(cost[np.isfinite(cost)], 0.5)) if np.isfinite(cost).any() else 1.0
    for abandon in (False, True):
        s, e, c, cost2 = search_costs(codes, table, ranges, thr, abandon=abandon)
        if abandon:  # abandoned cells: exact at or below the threshold, inf or exact above
            low = cost <= thr
            np.testing.assert_allclose(cost2[low], cost[low])
            assert np.all((cost2[~low] == np.inf) | np.isclose(cost2[~low], cost[~low]))
        else:
            np.testing.assert_allclose(cost2, cost)  # the branch-free cost pass: same values
        for got, want in zip((s, e, c), naive.template_hits(cost, start, thr, 0.5, ranges), strict=True):
            np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("seed", range(8))
def test_early_abandoning_cost_pass_matches_naive(seed):
    from mocapflow.plugins.relational._template_kernels import sdtw_cost, template_sdtw

    rng = np.random.default_rng(100 + seed)
    k = int(rng.integers(1, 12))
    lengths = rng.integers(1, 60, size=int(rng.integers(1, 6)))
    offsets = np.concatenate([[0], np.cumsum(lengths)])
    n = int(offsets[-1])
    codes = rng.integers(0, 1 << 31, size=n, dtype=np.int64)
    codes[4:9] = codes[3]  # runs of equal codes: the local costs are reused, possibly for more rows
    table = (rng.random((6400, k)) ** 3).astype(np.float32)  # many cheap cells: long live bands
    clip_of = np.repeat(np.arange(len(lengths)), lengths)
    ncost, nstart = naive.subsequence_dtw(_table_cost(table, codes), clip_of)
    fin = ncost[np.isfinite(ncost)]
    for bound in [0.0, np.inf] + ([float(np.quantile(fin, q)) for q in (0.05, 0.3, 0.7)] if len(fin) else []):
        cost = np.full(n, np.inf)
        # a bound per range: this one for every range but the first, which gets none
        bounds = np.full(len(lengths), bound)
        bounds[0] = np.inf
        sdtw_cost(codes, table, offsets[:-1].copy(), offsets[1:].copy(), cost, bounds)
        np.testing.assert_allclose(cost[: lengths[0]], ncost[: lengths[0]], rtol=1e-6)
        low = ncost <= bound
        np.testing.assert_allclose(cost[low], ncost[low], rtol=1e-6)
        above = ~low
        assert np.all((cost[above] == np.inf) | np.isclose(cost[above], ncost[above], rtol=1e-6))
        assert np.all(cost[above] > bound)
        # the pass with path starts abandons the same way: exact costs and starts at or below the bound
        c2, s2 = np.full(n, np.inf), np.full(n, -1, np.int64)
        template_sdtw(codes, table, offsets[:-1].copy(), offsets[1:].copy(), c2, s2, bound)
        np.testing.assert_allclose(c2[low], ncost[low], rtol=1e-6)
        fin_low = low & np.isfinite(ncost)
        np.testing.assert_array_equal(s2[fin_low], nstart[fin_low])
        assert np.all((c2[above] == np.inf) | np.isclose(c2[above], ncost[above], rtol=1e-6))


def test_window_minima_matches_naive():
    from mocapflow.plugins.relational._hit_kernels import window_minima

    rng = np.random.default_rng(3)
    cost = rng.random(50)
    cost[rng.random(50) < 0.2] = np.inf
    lo = rng.integers(0, 50, 20)
    hi = np.minimum(lo + rng.integers(0, 10, 20), 50)
    want = [cost[a:b].min() if b > a else np.inf for a, b in zip(lo, hi, strict=True)]
    np.testing.assert_array_equal(window_minima(cost, lo, hi), want)


def test_clip_labels_and_groups():
    from mocapflow.framework.errors import ConfigError
    from mocapflow.plugins.relational.template import HDM05_GROUP, HDM05_LABEL, clip_labels

    names = ["HDM_bd_kickLFront1Reps_001_120", "HDM_dg_squat1Reps_025_120", "01_02"]
    assert clip_labels(names, HDM05_LABEL) == ["kickLFront1Reps", "squat1Reps", None]
    assert clip_labels(names, HDM05_GROUP, "group") == ["bd", "dg", None]
    with pytest.raises(ConfigError, match="named group"):
        clip_labels(names, r"HDM_(\w+)")


def test_calibrate_threshold_between_positives_and_negatives():
    from mocapflow.plugins.relational.template_model import calibrate_threshold

    assert calibrate_threshold([0.1, 0.2], [0.5, 0.6]) == pytest.approx(0.35)  # midway: F1 = 1
    assert calibrate_threshold([0.1, 0.2], None, margin=0.5) == pytest.approx(0.3)
    assert calibrate_threshold([np.inf], [0.1]) == 0.1  # no finite positive: the fallback
    # overlapping classes: the cut keeping both positives beats the one losing one (F1 0.8 vs 0.67)
    assert 0.3 < calibrate_threshold([0.1, 0.3], [0.2, 0.9]) < 0.9


@pytest.mark.skipif(not HDM05.is_dir(), reason="needs the HDM05 cuts in ../shared/data/hdm05")
def test_fitted_templates_are_reused_through_reference(tmp_path):
    import pyarrow.parquet as pq

    from mocapflow.framework.runner import run_pipeline

    files = sorted(str(p) for c in ("kickLFront", "squat1") for p in HDM05.glob(f"*/*{c}*.amc"))
    yaml = tmp_path / "t.yaml"
    yaml.write_text(f"""name: t
workspace: ws
steps:
  motions: {{uses: formats.load, with: {{paths: {files!r}, fps: 30}}}}
  relational: {{uses: features.relational, input: motions}}
  fit: {{uses: matchers.template, inputs: {{database: relational, motions: motions}}, with: {{train: "^HDM_(bd|bk)_", plots: false}}}}
  reuse: {{uses: matchers.template, inputs: {{database: relational, motions: motions, reference: fit}}, with: {{plots: false}}}}
""")
    run_pipeline(yaml)
    ws = tmp_path / "ws"
    a, b = (pq.read_table(ws / s / "data.parquet").to_pylist() for s in ("fit", "reuse"))
    assert a == b and len(a) >= 12  # the same templates: the same hits (each class finds its 6 cuts at least)
    assert pq.read_table(ws / "reuse" / "templates.parquet")["label"].to_pylist() == ["kickLFront1Reps", "squat1Reps"]


def test_short_rival_cannot_silence_a_longer_motion():
    """A rival rejects only a stretch its path can span (K >= COVER x the hit's frames): a
    short template fitting a part of a long motion better does not remove the long hit,
    while a rival as long as the hit does (table and window scans agree)."""
    from mocapflow.plugins.relational.template import search_template
    from mocapflow.plugins.relational.template_cutoff import RivalTable, rival_mask

    long_ex = [_pattern(n, (0.1, 0.9)) for n in (60, 64, 68)]
    with7 = [x.copy() for x in long_ex]
    for x in with7:
        x[:, 7] = 1  # a feature the long template holds off throughout
    long_t = fit_class_template("long", long_ex, features="all")
    short = fit_class_template("short", [x[20:36] for x in with7], features="all")  # a 16-frame part
    long7 = fit_class_template("long7", with7, features="all")
    offsets = np.array([0, 64])
    codes = frame_codes(with7[1])
    s, e, _ = search_template(long_t, codes, offsets, threshold=0.9)
    assert len(s) and (e - s).max() > 2 * short.n_frames
    for rival, kept in ((short, True), (long7, False)):
        slow = rival_mask([long_t, rival], 0, s, e, codes, offsets)
        np.testing.assert_array_equal(slow, RivalTable.build([long_t, rival], codes, offsets).mask(0, s, e, offsets))
        assert bool(slow[np.argmax(e - s)]) == kept


def _two_class_setup():
    """Templates of two patterns (feature 3 on early / feature 5 on late) and a database
    holding both motions; template 0's loose bound also accepts the other pattern."""
    ex_a = [_pattern(n, (0.1, 0.5)) for n in (30, 34, 38)]
    ex_b = []
    for n in (30, 34, 38):
        x = np.zeros((n, 31), np.float32)
        x[:, 20] = 1
        x[int(0.5 * n) : int(0.9 * n), 5] = 1
        ex_b.append(x)
    ta = fit_class_template("a", ex_a, features="all")
    tb = fit_class_template("b", ex_b, features="all")
    db = np.concatenate([ex_a[1], ex_b[1], ex_a[0], ex_b[2]])
    offsets = np.array([0, 34, 68, 98, 136])
    return [ta, tb], frame_codes(db), offsets


def test_rival_cutoff_keeps_each_motion_for_its_own_template():
    from mocapflow.plugins.relational.template import cutoff_hits, search_template
    from mocapflow.plugins.relational.template_cutoff import RivalTable, rival_mask

    temps, codes, offsets = _two_class_setup()

    def clip_of(starts):
        return np.searchsorted(offsets, starts, side="right") - 1

    loose = [search_template(t, codes, offsets, threshold=0.6) for t in temps]  # no rival check
    assert set(clip_of(loose[0][0]).tolist()) >= {0, 1, 2}  # a loose bound: template a also hits b's motion
    got = cutoff_hits(temps, codes, offsets, threshold=0.6)
    assert set(clip_of(got[0][0]).tolist()) == {0, 2} and set(clip_of(got[1][0]).tolist()) == {1, 3}
    table = RivalTable.build(temps, codes, offsets)
    for which, (s, e, _) in enumerate(loose):  # the lookup table and the window scans agree
        np.testing.assert_array_equal(table.mask(which, s, e, offsets), rival_mask(temps, which, s, e, codes, offsets))
    with_table = cutoff_hits(temps, codes, offsets, threshold=0.6, rival_table=table)
    for a, b in zip(got, with_table, strict=True):
        np.testing.assert_array_equal(a[0], b[0])


def test_fusion_keeps_hits_whose_clip_the_numeric_search_supports():
    from mocapflow.plugins.relational.auto import fusion_mask, relative_cost_cut

    ncost = np.array([0.5, 0.6, 3.0, np.inf, 0.55, 5.0, 4.0, 4.5])
    hits = np.array([0, 2, 3, 4])
    cut = relative_cost_cut(ncost, 1.6)
    keep = fusion_mask(hits, ncost, 1.6)
    np.testing.assert_array_equal(keep, ncost[hits] <= cut)
    assert keep.tolist() == [True, False, False, True]
    assert fusion_mask(hits, ncost, None).all() and len(fusion_mask(np.zeros(0, int), ncost, 1.6)) == 0


def test_numeric_input_costs_per_query_and_clip():
    import pyarrow as pa

    from mocapflow.framework.errors import PipelineError
    from mocapflow.plugins.relational.matcher import RelationalMatcher

    class _DS:
        def __init__(self, producer):
            self.producer = producer

        def table(self, name, columns=None):
            return pa.table({"query_id": [0, 0, 1, 0], "clip_id": [7, 8, 7, 7], "cost": [2.0, 1.0, 3.0, 1.5]})

    got = RelationalMatcher._numeric_costs(_DS("matchers.search"))
    assert got == {0: {7: 1.5, 8: 1.0}, 1: {7: 3.0}}
    assert RelationalMatcher._numeric_costs(None) is None
    with pytest.raises(PipelineError, match="numeric must be a matcher step"):
        RelationalMatcher._numeric_costs(_DS("features.relational"))
