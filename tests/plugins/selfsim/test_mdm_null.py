"""The calibrated cleaner's test: detectors, the per-joint robust units and the conformal null
against naive references, calibration on similar words, the false-alarm knob, the shims, the
second injector family and bad input."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from naive.cleaning import synthetic_walk

from mocapflow.framework import quaternions as quat
from mocapflow.plugins.selfsim.calibrated import null as nullmod
from mocapflow.plugins.selfsim.calibrated.detectors import DETECTORS, SCALE_FLOOR, evidence
from mocapflow.plugins.selfsim.cleaner import CalibratedParams, MDMCleaner


def naive_units(ev: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per joint and detector, by lists: the median and the 0.95 quantile over it (floored)."""
    n, m, k = ev.shape
    c, s = np.zeros((m, k)), np.zeros((m, k))
    for j in range(m):
        for d in range(k):
            x = sorted(ev[:, j, d].tolist())
            c[j, d] = float(np.median(x))
            pos = 0.95 * (n - 1)
            lo = int(np.floor(pos))
            hi = min(lo + 1, n - 1)
            q95 = x[lo] + (pos - lo) * (x[hi] - x[lo])
            s[j, d] = max(q95 - c[j, d], SCALE_FLOOR[d])
    return c, s


def naive_p(pooled: list[float], s: float) -> float:
    return (1 + sum(1 for x in pooled if x >= s)) / (len(pooled) + 1)


def test_units_statistic_and_p_values_match_naive_references():
    rng = np.random.default_rng(0)
    ev = rng.gamma(1.0, 0.05, (300, 4, len(DETECTORS)))
    c, s = nullmod.robust_units(ev)
    nc, ns = naive_units(ev)
    np.testing.assert_allclose(c, nc)
    np.testing.assert_allclose(s, ns)
    null = nullmod.context_null([ev], [np.ones(300, bool)], ["a", "b", "c", "d"], ["x"])
    z = ((ev - nc) / ns).max(-1).ravel().tolist()
    np.testing.assert_allclose(np.sort(z), null.pooled)
    probe = np.array([min(z), float(np.median(z)), max(z) - 1e-9, max(z) + 1.0])
    p = null.p_values(probe)
    for v, got in zip(probe, p, strict=True):
        want = naive_p(z, v)
        if want >= nullmod.MIN_EXCEEDANCES / (len(z) + 1):
            assert got == pytest.approx(want)
        else:
            assert got <= want  # beyond the context's resolution: the shipped tail, never larger


def test_threshold_is_the_null_quantile_and_the_shipped_tail_beyond_it():
    rng = np.random.default_rng(1)
    pooled = np.sort(rng.standard_exponential(5000))
    ship = nullmod.shipped_null(["a"])
    null = nullmod.Null(np.zeros((1, 5)), np.ones((1, 5)), pooled, ship.alphas, ship.taus, "context")
    for rate in (0.1, 0.01, 0.005):
        assert np.mean(pooled > null.threshold(rate)) <= rate + 1.0 / len(pooled)
        assert np.mean(pooled > null.threshold(rate)) >= rate - 2.0 / len(pooled)
    # below the resolution (10 cells beyond): the context's level carried by the shipped shape, monotone
    levels = [null.threshold(r) for r in (2e-3, 1e-3, 1e-4, 1e-5)]
    assert all(a < b for a, b in zip(levels, levels[1:], strict=False))
    # the shipped null alone: its table, interpolated in log rate
    assert ship.threshold(ship.alphas[3]) == pytest.approx(ship.taus[3])
    # carried to a take twice as lively in its bulk: twice the level
    s = np.concatenate([2 * pooled, [1e6]])
    assert null.take_threshold(0.01, s) == pytest.approx(2 * null.threshold(0.01), rel=0.05)


def test_detectors_are_relative_to_the_consensus():
    walk = synthetic_walk(120, seed=2)
    q = quat.make_continuous(walk.rotations, axis=0)
    names = [None] * walk.n_joints
    for name, j in walk.skeleton.canonical.items():
        names[j] = name
    # the take equal to its consensus: no step, digression, hold or swap evidence anywhere
    ev = evidence(q, q, np.zeros(q.shape[:2]), names)
    assert ev.shape == q.shape[:2] + (len(DETECTORS),)
    assert np.abs(ev[..., [0, 1, 3, 4]]).max() < 1e-6
    bad = q.copy()
    j = walk.skeleton.canonical["lknee"]
    bad[60, j] = quat.mul(bad[60, j], quat.from_axis_angle(np.array([1.0, 0, 0]), np.deg2rad(40.0)))
    ev = evidence(bad, q, np.zeros(q.shape[:2]), names)
    assert np.argmax(ev[:, j, DETECTORS.index("step")]) == 60 and ev[60, j, 0] > np.deg2rad(30.0)


@pytest.fixture(scope="module")
def walk_take():
    clean = synthetic_walk(240, seed=5, name="take")
    ctx = [synthetic_walk(240, seed=s, name=f"ctx{s}") for s in (6, 7)]
    return clean, ctx


def test_calibration_spans_are_chosen_by_similarity_not_length(walk_take):
    from mocapflow.plugins.selfsim.calibrated.calibration import similar_spans

    clean, ctx = walk_take
    # a long clip of another motion (a still pose) and a short walk: the walk calibrates
    n = 3 * ctx[0].n_frames
    still = ctx[0].with_arrays(
        rotations=np.broadcast_to(ctx[0].rotations[:1], (n,) + ctx[0].rotations.shape[1:]).copy(),
        root_translation=np.zeros((n, 3)),
        name="still",
    )
    short = ctx[1].slice(0, int(6 * ctx[1].fps)).with_arrays(name="short")
    cleaner = MDMCleaner(write_bvh=False, heatmaps=False)
    res = cleaner.analyse(clean, [still, short])
    spans, share = similar_spans(res, [still, short], 24.0, 600)
    assert spans and {i for i, *_ in spans} == {1} and share > 0.2


def test_the_knob_sets_the_flagged_share_and_the_shims_warn(walk_take):
    clean, ctx = walk_take
    with pytest.warns(DeprecationWarning, match="calibrated.false_alarm_rate"):
        CalibratedParams(false_alarm=0.004)
    with pytest.warns(DeprecationWarning, match="seed is deprecated"):
        CalibratedParams(seed=1)
    with pytest.warns(DeprecationWarning, match="max_edit is deprecated"):
        CalibratedParams(max_edit=30.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        CalibratedParams(false_alarm_rate=1e-3)
    shares = []
    for rate in (1e-3, 1e-1):
        out = MDMCleaner(write_bvh=False, heatmaps=False, calibrated={"false_alarm_rate": rate}).clean(clean, ctx)
        shares.append(out.flags.mean())
        assert out.pvalue is not None and out.pvalue.shape == out.flags.shape
    assert shares[0] < shares[1] and 0.01 < shares[1] < 0.4


def test_family_b_injection_is_seeded_and_marks_what_it_moved():
    from mocapflow.plugins.selfsim.evaluation.injection_b import KINDS_B, inject_b

    walk = synthetic_walk(600, fps=120.0, seed=3)
    a, mask_a, err_a = inject_b(walk, seed=4, density=0.3)
    b, mask_b, _ = inject_b(walk, seed=4, density=0.3)
    assert np.array_equal(a.rotations, b.rotations) and np.array_equal(mask_a, mask_b)
    assert err_a and {e.kind for e in err_a} <= set(KINDS_B)
    moved = np.rad2deg(quat.geodesic_angle(a.rotations, walk.rotations)) > 5.0
    np.testing.assert_array_equal(moved, mask_a)


def test_bad_input_gets_a_message_naming_the_take(walk_take, caplog):
    clean, ctx = walk_take
    cleaner = MDMCleaner(write_bvh=False, heatmaps=False)
    tiny = clean.slice(0, int(10 * clean.fps / 24)).with_arrays(name="tiny")  # 10 analysis frames < a word
    with caplog.at_level("WARNING", logger="mocapflow.cleaning"):
        out = cleaner.clean(tiny, ctx)
    assert not out.flags.any() and out.edits.num_rows == 0
    assert "tiny" in caplog.text and "shorter than one motion word" in caplog.text
    caplog.clear()
    crumbs = [c.slice(0, 10).with_arrays(name=f"crumb{i}") for i, c in enumerate(ctx)]  # no usable word
    with caplog.at_level("WARNING", logger="mocapflow.cleaning"):
        out = cleaner.clean(clean, crumbs)
    assert out.calibration.source == "shipped" and "take:" in caplog.text
    rot = clean.rotations.copy()
    rot[5, 3] = np.nan
    from mocapflow.framework.errors import DataError

    with pytest.raises(DataError, match="'take' has NaN"):
        cleaner.clean(clean.with_arrays(rotations=rot), ctx)
