"""Session 7 of issue 14: the words cue (selfsim/word_noise.py) against its slow references
(tests/naive/cleaning_noise.py, tests/naive/cleaning_word_noise.py), and what it sees."""
from __future__ import annotations

import numpy as np
import pytest
from naive.cleaning_noise import naive_word_null
from naive.cleaning_word_noise import naive_word_jitter

from mocapflow.plugins.selfsim import noise, word_noise
from mocapflow.plugins.selfsim.cues import CUES


@pytest.fixture(scope="module")
def walk_analysis():
    from naive.cleaning import synthetic_walk

    from mocapflow.plugins.selfsim.mdm import MDMCleaner

    take = synthetic_walk(96, seed=5, name="take")
    context = [synthetic_walk(96, seed=s, name=f"ctx{s}") for s in (6, 7)]
    return MDMCleaner().analyse(take, context)


def test_word_amplitude_matches_the_naive_reference(walk_analysis):
    res = walk_analysis
    fast = word_noise.word_amplitude(res.neighbours[0], res.mean_texture, 2)
    slow = naive_word_null(res, 2)
    np.testing.assert_array_equal(np.isnan(fast), np.isnan(slow))
    np.testing.assert_allclose(fast[~np.isnan(fast)], slow[~np.isnan(slow)], atol=1e-7)
    assert np.isfinite(fast).mean() > 0.9
    # the loop version of noise.py agrees too
    np.testing.assert_allclose(np.nan_to_num(noise.word_null(res, 2), nan=-1), np.nan_to_num(fast, nan=-1), atol=1e-9)


def test_word_amplitude_skips_invalid_neighbours(walk_analysis):
    import dataclasses

    res = walk_analysis
    neigh = res.neighbours[0]
    target = neigh.target.copy()
    target[:, ::3, 1:] = -1  # every third word keeps one neighbour
    target[0, 1, :] = -1  # and one word of the first group none
    bent = dataclasses.replace(neigh, target=target)
    fast = word_noise.word_amplitude(bent, res.mean_texture, 3)
    slow = naive_word_null(dataclasses.replace(res, neighbours=[bent]), 3)
    np.testing.assert_array_equal(np.isnan(fast), np.isnan(slow))
    np.testing.assert_allclose(fast[~np.isnan(fast)], slow[~np.isnan(slow)], atol=1e-7)


@pytest.mark.parametrize("slack,erode", [(0, 0), (2, 0), (0, 2), (1, 1)])
def test_word_jitter_matches_the_naive_reference(walk_analysis, slack, erode):
    res = walk_analysis
    wamp = word_noise.word_amplitude(res.neighbours[0], res.mean_texture, 2)
    wamp[:4, 3] = np.nan  # uncovered cells: the cue is 0 there (unless slack reaches a covered one)
    fast = word_noise.word_jitter(res.texture.q, res.mean_texture, wamp, 2, slack, erode=erode)
    slow = naive_word_jitter(res.texture.q, res.mean_texture, wamp, 2, slack, erode=erode)
    np.testing.assert_allclose(fast, slow, atol=1e-9)
    if slack == 0:
        assert not fast[:4, 3].any()


def test_words_cue_sees_noise_and_not_the_clean_walk(walk_analysis):
    from mocapflow.framework import quaternions as quat

    res = walk_analysis
    q = res.texture.q.copy()
    rng = np.random.default_rng(3)
    j = 5
    axis = rng.normal(size=(12, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    q[40:52, j] = quat.mul(q[40:52, j], quat.from_axis_angle(axis, np.deg2rad(rng.normal(0, 15, 12))))
    wamp = word_noise.word_amplitude(res.neighbours[0], res.mean_texture, 2)
    clean = word_noise.word_jitter(res.texture.q, res.mean_texture, wamp, 2)
    noisy = word_noise.word_jitter(q, res.mean_texture, wamp, 2)
    assert np.median(noisy[42:50, j]) > 1.0 > np.quantile(clean, 0.99)
    np.testing.assert_array_equal(noisy[:, [k for k in range(q.shape[1]) if k != j]],
                                  clean[:, [k for k in range(q.shape[1]) if k != j]])


def test_words_cue_off_by_default_and_fitted_when_asked():
    from naive.cleaning import synthetic_walk

    from mocapflow.plugins.selfsim.mdm import MDMCleaner

    take = synthetic_walk(96, seed=5, name="take")
    context = [synthetic_walk(120, seed=s, name=f"ctx{s}") for s in (6, 7, 8)]
    k = CUES.index("words")
    off = MDMCleaner().clean(take, context)
    assert off.calibration.word_half is None and not np.isfinite(off.calibration.weights[k])
    on = MDMCleaner(cues=("digression", "acceleration", "mirror", "freeze", "jitter", "words"),
                    cue_fa={"words": 0.05}).clean(take, context)
    assert on.calibration.word_half == 2 and np.isfinite(on.calibration.weights[k])
    res = on.analysis
    wamp = word_noise.word_amplitude(res.neighbours[0], res.mean_texture, 2)
    ev = on.calibration.evidence(res.texture.q, res.mean_texture, res.spread, res.joints, wamp)
    raw = word_noise.word_jitter(res.texture.q, res.mean_texture, wamp, 2)
    np.testing.assert_allclose(ev[..., k], raw / (on.calibration.levels[:, k] * on.calibration.weights[k]))


def test_merged_runs_do_not_bridge_body_jolt_cells(walk_analysis):
    """merge_gap joins two flagged runs of a joint through the gap; ``no_merge`` (the
    acceleration flags acc_body dropped as a whole-body jolt, session 7) stops it there: the
    gap cells are left exactly as they were, the two runs are still repaired."""
    import dataclasses

    from mocapflow.framework import quaternions as quat
    from mocapflow.plugins.selfsim.bounded_repair import bounded_repair

    res = walk_analysis
    j = res.joints.index("lknee")
    q = res.texture.q.copy()
    z = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (8, 3))
    q[40:48, j] = quat.mul(q[40:48, j], quat.from_axis_angle(z, np.full(8, np.deg2rad(25.0))))
    bad = dataclasses.replace(res, texture=dataclasses.replace(res.texture, q=q))
    flags = np.zeros(q.shape[:2], bool)
    flags[40:43, j] = flags[45:48, j] = True
    gap = np.zeros_like(flags)
    gap[43:45, j] = True
    merged, edited, _ = bounded_repair(bad, flags, merge_gap=3)
    kept, edited2, _ = bounded_repair(bad, flags, merge_gap=3, no_merge=gap)
    assert edited[43:45, j].all()
    assert not edited2[43:45, j].any() and np.array_equal(kept[43:45, j], q[43:45, j])
    assert edited2[40:43, j].any() and edited2[45:48, j].any()
    np.testing.assert_array_equal(kept[:, [c for c in range(q.shape[1]) if c != j]],
                                  merged[:, [c for c in range(q.shape[1]) if c != j]])


def _material(seed: int = 0):
    from mocapflow.plugins.selfsim.calibration import CalibrationMaterial
    from mocapflow.plugins.selfsim.cues import RAW_CUES

    rng = np.random.default_rng(seed)
    cues, truth = [], []
    for _ in range(2):
        t, m = 90, 4
        c = {k: np.abs(rng.normal(0.02, 0.01, (t, m))) for k in RAW_CUES}
        c["hold"] = np.zeros((t, m))
        tr = np.zeros((t, m), bool)
        tr[40:48, 1] = True
        c["word_jitter"] = np.abs(rng.normal(0.1, 0.05, (t, m)))
        c["word_jitter"][36:52, 1] += 2.0  # the error and its leak of 4 frames each side
        cues.append(c)
        truth.append(tr)
    return CalibrationMaterial(cues, truth, ["a", "b"], "context", None, None)


def test_null_reach_leaves_out_the_leak_and_floor_only_keeps_the_cue_out_of_the_greedy():
    from mocapflow.plugins.selfsim.calibration import fit_calibration
    from mocapflow.plugins.selfsim.fusion import _FLOORS, _near

    mat = _material()
    k = CUES.index("words")
    allc = ("digression", "acceleration", "mirror", "freeze", "jitter", "words")
    plain = fit_calibration(mat, 0.05, cues=allc, word_half=2)
    far = fit_calibration(mat, 0.05, cues=allc, word_half=2, null_reach={"words": 4})
    # the slow way: the 0.99 quantile of joint 1's clean cells more than 4 frames from the error
    vals = np.concatenate([c["word_jitter"][:, 1][[all(not t[g, 1] for g in range(max(0, f - 4), min(90, f + 5)))
                                                   for f in range(90)]] for c, t in zip(mat.cues, mat.truth)])
    assert far.levels[1, k] == pytest.approx(max(np.quantile(vals, 0.99), _FLOORS[k]))
    assert plain.levels[1, k] > 1.0 > far.levels[1, k]
    np.testing.assert_array_equal(_near(mat.truth[0], 4)[:, 1], np.isin(np.arange(90), np.arange(36, 52)))
    # the greedy uses the words cue when it may; with floor_only it does not, and a cue_fa floor sets it
    assert np.isfinite(far.weights[k])
    off = fit_calibration(mat, 0.05, cues=allc, word_half=2, null_reach={"words": 4}, floor_only=("words",))
    assert not np.isfinite(off.weights[k])
    floor = fit_calibration(mat, 0.05, cues=allc, word_half=2, null_reach={"words": 4}, floor_only=("words",),
                            cue_fa={"words": 0.01})
    assert np.isfinite(floor.weights[k])
