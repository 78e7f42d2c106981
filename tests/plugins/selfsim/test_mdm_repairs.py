"""Swaps found by their edges, offsets repaired between their jumps, the decision's rules and
the protocol's source-glitch mask, against naive references and on a synthetic walk."""

from __future__ import annotations

import numpy as np
from naive.cleaning import synthetic_walk
from naive.cleaning_repairs import naive_edge_benefit, naive_forward_offset

from mocapflow.framework import quaternions as quat
from mocapflow.plugins.selfsim.calibrated import cues
from mocapflow.plugins.selfsim.calibrated.offsets import _forward_offsets, offset_interval, remove_offset
from mocapflow.plugins.selfsim.calibrated.swaps import edge_benefit, swap_edges


def _walk():
    walk = synthetic_walk(160, seed=3)
    names = [None] * walk.n_joints
    for name, j in walk.skeleton.canonical.items():
        names[j] = name
    return quat.make_continuous(walk.rotations, axis=0), names, walk.skeleton.canonical


def _swap(q, c, a, b, side=("lshoulder", "lelbow", "lwrist"), other=("rshoulder", "relbow", "rwrist")):
    left, right = [c[j] for j in side], [c[j] for j in other]
    bad = q.copy()
    bad[a:b, left] = cues.mirror(q[a:b, right])
    bad[a:b, right] = cues.mirror(q[a:b, left])
    return bad, left, right


def test_edge_benefit_matches_naive_reference():
    rng = np.random.default_rng(1)
    q = quat.make_continuous(quat.normalize(rng.standard_normal((14, 6, 4))), axis=0)
    left, right = np.array([0, 1, 2]), np.array([3, 4, 5])
    np.testing.assert_allclose(edge_benefit(q, left, right), naive_edge_benefit(q, [0, 1, 2], [3, 4, 5]), atol=1e-7)
    track = q[:, 2]
    fwd = _forward_offsets(track)
    for f in range(2, len(track)):
        ref = np.array(naive_forward_offset(track, f))
        assert min(np.abs(fwd[f] - ref).max(), np.abs(fwd[f] + ref).max()) < 1e-9


def test_swap_edges_find_the_swap_exactly_and_nothing_on_the_clean_walk():
    q, names, c = _walk()
    assert swap_edges(q, names) == []
    bad, left, right = _swap(q, c, 50, 71)
    found = [(a, b) for lc, rc, a, b in swap_edges(bad, names) if set(lc.tolist()) == set(left)]
    assert found == [(50, 71)]
    legs = [r for r in swap_edges(bad, names) if set(r[0].tolist()) != set(left)]
    assert legs == []


def test_offset_interval_recovers_a_partly_flagged_offset():
    q, names, c = _walk()
    j = c["lknee"]
    track = q[:, j].copy()
    off = quat.from_axis_angle(np.array([0.0, 0.6, 0.8]), np.deg2rad(35.0))
    bad = track.copy()
    bad[60:74] = quat.mul(track[60:74], off)
    found = offset_interval(bad, 64, 67, np.deg2rad(8.0))  # only three frames of it flagged
    assert found is not None and found[:2] == (60, 74)
    rep = remove_offset(bad, *found)
    assert np.rad2deg(quat.geodesic_angle(rep, track[60:74])).max() < 3.0
    # the clean track has no two consistent jumps
    assert offset_interval(track, 64, 67, np.deg2rad(8.0)) is None


def test_cleaner_repairs_a_swap_found_by_its_edges_alone():
    from mocapflow.plugins.selfsim.cleaner import MDMCleaner, MDMParams, clean_motion

    walk = synthetic_walk(200, seed=4)
    ctx = [synthetic_walk(200, seed=s, name=f"c{s}") for s in (5, 6)]
    c = walk.skeleton.canonical
    rot, left, right = _swap(quat.make_continuous(walk.rotations, axis=0), c, 80, 100)
    bad = walk.with_arrays(rotations=rot)
    cl = MDMCleaner(MDMParams(write_bvh=False, heatmaps=False, calibrated={"frames": 200}))
    out = clean_motion(cl, bad, ctx)
    tex = out.analysis.texture
    cols = [list(tex.joint_index).index(j) for j in left + right]
    clean_tex = quat.make_continuous(walk.rotations, axis=0)[:, tex.joint_index]
    # the test fires on the swap and the whole swapped interval is swapped back exactly
    assert out.flags[80:100][:, cols].any()
    assert "swap" in set(out.cue[80:100][:, cols][out.flags[80:100][:, cols]].ravel())
    err = np.rad2deg(quat.geodesic_angle(out.repaired[80:100][:, cols], clean_tex[80:100][:, cols]))
    assert err.max() < 1.0
    # and the clean walk is left alone by the swap search
    assert not clean_motion(cl, walk, ctx).flags[:, cols].any()


def test_source_glitches_marks_a_flip_not_a_raised_arm():
    from mocapflow.plugins.selfsim.evaluation.scores import source_glitches

    q, names, c = _walk()
    tex = q.copy()
    a = c["lankle"]
    flip = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.deg2rad(170.0))
    tex[70:85, a] = quat.mul(q[70:85, a], flip)
    # a shoulder raised 100 degrees over a second: far from its mean pose, but gradually
    s = c["lshoulder"]
    ramp = np.deg2rad(np.clip(np.arange(len(q)) - 100, 0, 24) * 100.0 / 24)
    tex[:, s] = quat.mul(q[:, s], quat.from_axis_angle(np.broadcast_to(np.array([0.0, 0.0, 1.0]), (len(q), 3)), ramp))
    tex = quat.make_continuous(tex, axis=0)
    g = source_glitches(tex)
    assert g[70:85, a].all() and not g[:60, a].any() and not g[95:, a].any()
    assert not g[:, s].any()
    assert not source_glitches(q).any()
