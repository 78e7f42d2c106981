"""analyses.reconstruct: the knee/elbow sides chosen over the take, the prior's typical
neighbour distances and the per-frame confidence."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest
from test_reconstruct import periodic_motion

from mocapflow.framework import DataError
from mocapflow.plugins.similarity.applications.reconstruct import (
    MODEL,
    ReconstructParams,
    reconstruct,
    reconstruct_positions,
    typical_distances,
)
from mocapflow.plugins.similarity.applications.reconstruct_prior import build_store, local_positions
from mocapflow.plugins.similarity.applications.reconstruct_sides import consistent_sides, swivel_candidates
from mocapflow.plugins.similarity.applications.reconstruct_synthetic import (
    PriorCache,
    synthetic_heading,
    synthetic_markers,
)


@pytest.fixture(scope="module")
def store():
    return build_store(
        [
            periodic_motion(90, 0.0, name="a", subject="s1", scale=1.15),
            periodic_motion(60, 0.13, amp=0.9, name="b", subject="s1", scale=1.15),
            periodic_motion(60, 0.31, amp=1.1, name="c", subject="s2", scale=1.15),
        ]
    )


def _swivel_path_numpy(unary: np.ndarray, pts: np.ndarray, w_t: float) -> np.ndarray:
    """The slow twin of ``_reconstruct_kernels.swivel_path``: every path scored, the least
    total cost kept (ties: the first path in lexicographic order)."""
    t_len, n_s = unary.shape
    best, arg = np.inf, None
    for path in itertools.product(range(n_s), repeat=t_len):
        cost = sum(unary[t, s] for t, s in enumerate(path))
        cost += sum(w_t * np.sum((pts[t, path[t]] - pts[t - 1, path[t - 1]]) ** 2) for t in range(1, t_len))
        if cost < best - 1e-12:
            best, arg = cost, path
    return np.array(arg)


def test_swivel_path_kernel_matches_numpy_twin():
    from mocapflow.plugins.similarity.applications._reconstruct_kernels import swivel_path

    rng = np.random.default_rng(2)
    for t_len, n_s in ((1, 3), (4, 3), (5, 4), (6, 2)):
        for _ in range(3):
            unary = rng.uniform(0, 2, (t_len, n_s))
            pts = rng.normal(size=(t_len, n_s, 3))
            w = float(rng.uniform(0.1, 3))
            assert swivel_path(unary, pts, w).tolist() == _swivel_path_numpy(unary, pts, w).tolist()
    assert len(swivel_path(np.zeros((0, 3)), np.zeros((0, 3, 3)), 1.0)) == 0


def test_typical_distances_match_a_loop():
    rng = np.random.default_rng(4)
    f = rng.normal(size=(40, 5))
    groups = np.repeat(np.arange(4), 10)
    fast = typical_distances(f, groups, n_sample=7)
    sample = np.unique(np.linspace(0, 39, 7).astype(int))
    profiles = []
    for i in sample:
        d = sorted(np.linalg.norm(f[j] - f[i]) for j in range(40) if groups[j] != groups[i])
        profiles.append([np.mean(d[: k + 1]) for k in range(len(d))])
    want = np.median(np.array(profiles), 0)
    assert np.allclose(fast[: len(want)], want) and np.allclose(fast[len(want) :], want[-1])


def test_a_knee_flipped_to_the_wrong_side_is_brought_back(store):
    truth = periodic_motion(40, 0.5 / 30, yaw_deg=30, name="t")
    prior = PriorCache(store).for_motion(truth, "none")
    joints = list(prior.joints)
    pos = truth.canonical_positions(prior.joints)
    local = local_positions(pos, prior.joints)
    heading = synthetic_heading(truth, 0.0)
    hip, knee, ankle = (joints.index(j) for j in ("lhip", "lknee", "lankle"))
    flipped = local.copy()
    flipped[12:20, knee] = swivel_candidates(local, hip, knee, ankle, 2)[12:20, 1]  # 180 degrees about hip-ankle
    assert np.linalg.norm(flipped[12:20, knee] - local[12:20, knee], axis=-1).min() > 0.05
    limit = consistent_sides(flipped, heading, pos[:, 0], prior, MODEL, 1.0)
    assert np.abs(flipped[:, knee] - local[:, knee]).max() < 0.02
    assert limit.shape == (40,) and np.all(limit >= 0)
    # one state (the solve's side only): the flip stays
    again = local.copy()
    again[12:20, knee] = swivel_candidates(local, hip, knee, ankle, 2)[12:20, 1]
    kept = again.copy()
    consistent_sides(kept, heading, pos[:, 0], prior, replace(MODEL, swivel_states=1), 1.0)
    assert np.allclose(kept, again, atol=1e-9)


def test_swivel_candidates_keep_the_bone_lengths(store):
    m = periodic_motion(10, yaw_deg=10)
    local = local_positions(m.canonical_positions(store.joints), store.joints)
    j = list(store.joints)
    a, b, c = j.index("rshoulder"), j.index("relbow"), j.index("rwrist")
    mids = swivel_candidates(local, a, b, c, 8)
    assert np.allclose(mids[:, 0], local[:, b])
    l1 = np.linalg.norm(local[:, b] - local[:, a], axis=-1)
    l2 = np.linalg.norm(local[:, c] - local[:, b], axis=-1)
    assert np.allclose(np.linalg.norm(mids - local[:, None, a], axis=-1), l1[:, None])
    assert np.allclose(np.linalg.norm(mids - local[:, None, c], axis=-1), l2[:, None])


def test_confidence_drops_where_a_marker_teleports(store):
    test = periodic_motion(60, 0.5 / 30, yaw_deg=-40, name="t")
    prior = PriorCache(store).for_motion(test, "none")
    markers = synthetic_markers(test)
    heading = synthetic_heading(test)
    params = ReconstructParams(k=16)
    clean = reconstruct(markers, prior, params, root_heading=heading, fps=30.0)
    assert clean.confidence.shape == (60,) and np.all((clean.confidence > 0) & (clean.confidence <= 1))
    world, head = reconstruct_positions(markers, prior, params, root_heading=heading)
    assert np.allclose(world, clean.positions) and np.allclose(head, clean.heading)
    bad = markers.copy()
    bad[30:33, 2] += np.array([0.5, 0.0, 0.0])  # the left wrist marker jumps 50 cm for 3 frames
    r = reconstruct(bad, prior, params, root_heading=heading, fps=30.0)
    others = np.r_[0:25, 38:60]
    assert r.confidence[30:33].max() < 0.2 < np.median(r.confidence[others])
    assert r.confidence[30:33].max() < 0.25 * np.median(clean.confidence[30:33])
    assert np.all(r.novelty[30:33] > 1.5 * clean.novelty[30:33])
    with pytest.raises(DataError, match="fps"):
        reconstruct(markers, prior, params, fps=0.0)


def test_the_same_motion_at_120_hz_keeps_its_sides(store):
    """The side's temporal term is per second: a 120 Hz take gives the 30 Hz result."""
    from mocapflow.framework.normalize import resample

    test = periodic_motion(30, 0.5 / 30, yaw_deg=20, name="t")
    fast = resample(test, 120.0)
    prior = PriorCache(store).for_motion(test, "none")
    params = ReconstructParams(k=16)
    slow = reconstruct(synthetic_markers(test), prior, params, root_heading=synthetic_heading(test), fps=30.0)
    quick = reconstruct(synthetic_markers(fast), prior, params, root_heading=synthetic_heading(fast), fps=120.0)
    truth_fast = fast.canonical_positions(prior.joints)
    truth_slow = test.canonical_positions(prior.joints)
    err_fast = np.linalg.norm(quick.positions - truth_fast, axis=-1).mean() * 100
    err_slow = np.linalg.norm(slow.positions - truth_slow, axis=-1).mean() * 100
    assert err_fast < 1.5 and err_slow < 1.5


def test_reused_neighbours_give_the_same_reconstruction(store, monkeypatch):
    from mocapflow.plugins.similarity.applications import reconstruct as rec_module

    test = periodic_motion(30, 0.5 / 30, yaw_deg=10, name="t")
    prior = PriorCache(store).for_motion(test, "none")
    args = (synthetic_markers(test), prior, ReconstructParams(k=16))
    kept = reconstruct(*args, root_heading=synthetic_heading(test))
    monkeypatch.setattr(rec_module, "NEIGHBOUR_CACHE", 0)
    again = reconstruct(*args, root_heading=synthetic_heading(test))
    assert np.array_equal(kept.positions, again.positions) and np.array_equal(kept.confidence, again.confidence)


def test_smooth_heading_averages_across_the_wrap():
    from mocapflow.plugins.similarity.applications.reconstruct import smooth_heading

    h = np.array([3.1, -3.1, 3.1, -3.1, 3.1])  # jitter about +-pi
    out = smooth_heading(h, 1)
    loop = [
        np.mean(
            np.unwrap(h)[max(i - 1, 0) : i + 2].tolist()
            + ([np.unwrap(h)[0]] if i == 0 else [])
            + ([np.unwrap(h)[-1]] if i == 4 else [])
        )
        for i in range(5)
    ]
    assert np.allclose(out, loop) and np.abs(np.angle(np.exp(1j * (out - np.pi)))).max() < 0.1
    assert np.allclose(smooth_heading(h, 0), np.unwrap(h)) and len(smooth_heading(np.zeros(0), 2)) == 0
