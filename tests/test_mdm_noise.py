"""Session 6 round 2 of issue 14: the bounded noise repair (selfsim/noise.py) against its slow
reference (tests/naive/cleaning_noise.py), and what it does to clean and noisy joints."""
from __future__ import annotations

import numpy as np
from naive.cleaning_noise import naive_noise_repair

from mocapflow.framework import quaternions as quat
from mocapflow.plugins.selfsim import noise
from mocapflow.plugins.selfsim.cues import rotation_vectors


def _walkish(t: int, m: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A smooth take (T, m, 4) and a consensus near it (a slow, smooth departure)."""
    rng = np.random.default_rng(seed)
    f = np.arange(t)[:, None, None]
    amp = rng.uniform(0.2, 0.8, (1, m, 3))
    ph = rng.uniform(0, 6, (1, m, 3))
    rv = amp * np.sin(2 * np.pi * f / 24.0 + ph)
    take = noise.rotation_exp(rv)
    drift = 0.03 * np.sin(2 * np.pi * f / 60.0 + ph)
    mean = quat.normalize(quat.mul(take, noise.rotation_exp(drift)))
    return take, mean


def test_rotation_exp_inverts_rotation_vectors():
    rng = np.random.default_rng(1)
    v = rng.normal(0, 0.6, (50, 3))
    v = v[np.linalg.norm(v, axis=-1) < 3.0]
    np.testing.assert_allclose(rotation_vectors(noise.rotation_exp(v)), v, atol=1e-9)


def test_window_mean_matches_loops():
    rng = np.random.default_rng(2)
    x = rng.normal(size=(13, 2, 3))
    out = noise.window_mean(x, 2)
    for t in range(13):
        np.testing.assert_allclose(out[t], x[max(0, t - 2):t + 3].mean(0))


def test_noise_repair_matches_the_naive_reference():
    take, mean = _walkish(40, 3)
    rng = np.random.default_rng(3)
    bad = take.copy()
    bad[10:22, 1] = quat.normalize(quat.mul(take[10:22, 1], noise.rotation_exp(rng.normal(0, 0.26, (12, 3)))))
    mask = np.zeros((40, 3), bool)
    mask[8:24, 1] = True
    mask[30:35, 2] = True
    new, edited = noise.noise_repair(bad, mean, mask, half=2, factor=2.0)
    n_new, n_edited = naive_noise_repair(bad, mean, mask, 2, 2.0)
    np.testing.assert_array_equal(edited, n_edited)
    np.testing.assert_allclose(np.abs(np.sum(new * n_new, -1)), 1.0, atol=1e-9)
    assert edited[12:20, 1].sum() >= 6 and not edited[~mask].any()


def test_noise_repair_lowers_the_error_and_leaves_clean_cells_alone():
    take, mean = _walkish(60, 4, seed=4)
    rng = np.random.default_rng(5)
    bad = take.copy()
    bad[20:34, 0] = quat.normalize(quat.mul(take[20:34, 0], noise.rotation_exp(rng.normal(0, 0.26, (14, 3)))))
    mask = np.ones((60, 4), bool)  # flagged everywhere: the clean joints must stay exact
    new, edited = noise.noise_repair(bad, mean, mask)
    assert not edited[:, 1:].any()
    np.testing.assert_array_equal(new[:, 1:], bad[:, 1:])
    err0 = quat.geodesic_angle(bad[20:34, 0], take[20:34, 0]) ** 2
    err1 = quat.geodesic_angle(new[20:34, 0], take[20:34, 0]) ** 2
    assert err1.sum() < 0.6 * err0.sum()
    # bounded: no cell moves by more than its amplitude beyond the null
    _, amp = noise.lowpassed(bad, mean, 2)
    cap = np.maximum(amp - 2.0 * np.maximum(np.median(amp, 0, keepdims=True), noise.AMP_FLOOR), 0)
    assert np.all(quat.geodesic_angle(new, bad) <= cap + 1e-6)


def test_spike_keep_repairs_a_departure_from_the_consensus_not_a_turn_it_shares():
    from mocapflow.plugins.selfsim.spikes import repair_spikes, spike_runs

    t = 60
    ax = np.array([0.3, 1.0, -0.2]) / np.linalg.norm([0.3, 1.0, -0.2])
    clean = quat.from_axis_angle(np.broadcast_to(ax, (t, 3)), 0.03 * np.arange(t))[:, None]
    q = clean.copy()
    z = np.array([0.0, 0.0, 1.0])
    q[30:32, 0] = quat.mul(q[30:32, 0], quat.from_axis_angle(z, np.array(np.deg2rad(40.0))))
    runs = spike_runs(q, 6.0)
    # the consensus shares 40 % of the excursion (a clean turn its KNN words make too)
    shared = clean.copy()
    shared[30:32, 0] = quat.mul(shared[30:32, 0], quat.from_axis_angle(z, np.array(np.deg2rad(16.0))))
    done_any = repair_spikes(q, shared, q.copy(), runs)
    done_keep = repair_spikes(q, shared, q.copy(), runs, keep=0.5)
    assert done_any[30:32, 0].all() and not done_keep.any()
    # a consensus without the excursion: repaired either way, exactly
    new = q.copy()
    assert repair_spikes(q, clean, new, runs, keep=0.5)[30:32, 0].all()
    assert quat.geodesic_angle(new[:, 0], clean[:, 0]).max() < 1e-6


def test_glitch_returns_marks_a_jump_and_return_not_a_turn():
    from mocapflow.plugins.selfsim.clean_scores import glitch_returns

    t = 50
    ax = np.array([0.3, 1.0, -0.2]) / np.linalg.norm([0.3, 1.0, -0.2])
    q = np.repeat(quat.from_axis_angle(np.broadcast_to(ax, (t, 3)), 0.02 * np.arange(t))[:, None], 2, axis=1)
    z = np.array([0.0, 0.0, 1.0])
    q[20:26, 0] = quat.mul(q[20:26, 0], quat.from_axis_angle(z, np.array(np.deg2rad(80.0))))  # away and back
    q[20:, 1] = quat.mul(q[20:, 1], quat.from_axis_angle(z, np.array(np.deg2rad(80.0))))  # away, stays
    g = glitch_returns(q)
    assert g[20:26, 0].all() and not g[:17, 0].any() and not g[29:, 0].any() and not g[:, 1].any()


def test_word_null_matches_the_naive_reference():
    from naive.cleaning import synthetic_walk
    from naive.cleaning_noise import naive_word_null

    from mocapflow.plugins.selfsim.mdm import MDMCleaner

    take = synthetic_walk(96, seed=5, name="take")
    context = [synthetic_walk(96, seed=s, name=f"ctx{s}") for s in (6, 7)]
    res = MDMCleaner().analyse(take, context)
    fast = noise.word_null(res, 2)
    slow = naive_word_null(res, 2)
    np.testing.assert_array_equal(np.isnan(fast), np.isnan(slow))
    np.testing.assert_allclose(fast[~np.isnan(fast)], slow[~np.isnan(slow)], atol=1e-7)
    assert np.isfinite(fast).mean() > 0.9
