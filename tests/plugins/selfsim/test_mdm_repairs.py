"""Swaps found by their edges, offsets repaired between their jumps, the decision's rules and
the protocol's source-glitch mask, against naive references and on a synthetic walk."""

from __future__ import annotations

import numpy as np
from naive.cleaning import synthetic_walk
from naive.cleaning_repairs import naive_edge_benefit, naive_forward_offset

from mocapflow.framework import quaternions as quat
from mocapflow.plugins.selfsim.calibrated import cues
from mocapflow.plugins.selfsim.calibrated.constants import CUES
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
    # every cell the swap moved by an error's size is reported, and only as a swap (cells it
    # moved less are swapped back too, not claimed: FLAG_MIN_DEG)
    moved = np.rad2deg(quat.geodesic_angle(tex.q[80:100][:, cols], clean_tex[80:100][:, cols])) >= 10.0
    assert moved.sum() > 0.5 * moved.size and out.flags[80:100][:, cols][moved].all()
    assert set(out.cue[80:100][:, cols][out.flags[80:100][:, cols]].ravel()) == {"mirror"}
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


def test_digression_only_runs_need_another_cue():
    from mocapflow.plugins.selfsim.calibrated.decision import _agreeing

    flags = np.zeros((20, 2), bool)
    flags[3:6, 0] = flags[10:13, 0] = flags[3:6, 1] = True
    dom = np.full((20, 2), CUES.index("digression"))
    dom[4, 1] = CUES.index("acceleration")  # a mixed run is never dropped
    ev = np.zeros((20, 2, len(CUES)))
    ev[13, 0, CUES.index("acceleration")] = 0.5  # the second run has a jump next to it
    out = _agreeing(flags, dom, ev, 0.3)
    assert not out[3:6, 0].any() and out[10:13, 0].all() and out[3:6, 1].all()


def test_a_whole_body_jolt_is_no_joint_error():
    from mocapflow.plugins.selfsim.calibrated.decision import _body_jolts_dropped

    acc, dig = CUES.index("acceleration"), CUES.index("digression")
    flags = np.zeros((10, 5), bool)
    dom = np.full((10, 5), acc)
    flags[4, :3] = True  # three joints jolt at once
    flags[7, 1] = True  # one joint's spike
    flags[4, 4], dom[4, 4] = True, dig  # another cue at the jolt frame is kept
    out = _body_jolts_dropped(flags, dom, 3)
    assert not out[4, :3].any() and out[7, 1] and out[4, 4]
    assert np.array_equal(_body_jolts_dropped(flags, dom, 4), flags)


def test_a_freeze_flag_grows_over_the_whole_still_interval():
    from mocapflow.plugins.selfsim.calibrated.decision import _freezes_grown

    walk = synthetic_walk(60, seed=1)
    q = quat.make_continuous(walk.rotations, axis=0)[:, :3].copy()
    q[20:35, 1] = q[20, 1]  # joint 1 frozen over frames 20-34
    fz = CUES.index("freeze")
    flags = np.zeros((60, 3), bool)
    dom = np.full((60, 3), CUES.index("digression"))
    flags[26:29, 1], dom[26:29, 1] = True, fz  # the freeze cue sees the middle only
    flags[40, 0] = True  # a digression flag elsewhere is untouched
    out, dom2 = _freezes_grown(flags, dom, q, np.deg2rad(0.05))
    assert out[20:35, 1].all() and not out[:20, 1].any() and not out[35:, 1].any()
    assert np.all(dom2[20:35, 1] == fz) and out[40, 0] and out.sum() == 16


def _rot(q, deg, axis=(0.0, 0.6, 0.8)):
    return quat.mul(q, quat.from_axis_angle(np.asarray(axis), np.deg2rad(deg)))


def test_weak_runs_are_moved_in_proportion_to_their_evidence():
    from mocapflow.plugins.selfsim.calibrated.decision import shrink_weak_runs

    q = quat.make_continuous(synthetic_walk(40, seed=2).rotations, axis=0)[:, :3].copy()
    new = q.copy()
    new[5:7, 0] = _rot(q[5:7, 0], 20.0)  # weak run: evidence 1.25
    new[20, 1] = _rot(q[20, 1], 40.0)  # strong run: evidence 4
    new[30, 2] = _rot(q[30, 2], 20.0)  # weak, but decided by a cue not shrunk
    edited = np.any(new != q, axis=-1)
    ev = np.zeros(edited.shape)
    ev[5:7, 0], ev[20, 1], ev[30, 2] = [1.1, 1.25], 4.0, 1.1
    eligible = edited.copy()
    eligible[30, 2] = False
    out = shrink_weak_runs(q, new, edited, np.zeros_like(edited), ev, eligible, full=2.0)
    got = np.rad2deg(quat.geodesic_angle(out, q))
    np.testing.assert_allclose(got[5:7, 0], 0.25 * 20.0, atol=1e-6)  # (1.25 - 1) / (2 - 1)
    assert abs(got[20, 1] - 40.0) < 1e-6 and abs(got[30, 2] - 20.0) < 1e-6
    assert np.array_equal(out[~edited], q[~edited])


def test_freeze_growth_stops_where_the_consensus_is_still_too():
    from mocapflow.plugins.selfsim.calibrated.decision import _freezes_grown

    walk = quat.make_continuous(synthetic_walk(60, seed=2).rotations, axis=0)[:, :3]
    q = walk.copy()
    q[20:35, 1] = q[20, 1]  # joint 1 still over frames 20-34
    mean_q = q.copy()
    mean_q[20:35, 1] = walk[20:35, 1]  # the consensus moves on ...
    mean_q[28:35, 1] = mean_q[28, 1]  # ... then holds still from frame 28
    fz = CUES.index("freeze")
    flags = np.zeros((60, 3), bool)
    dom = np.full((60, 3), CUES.index("digression"))
    flags[24:26, 1], dom[24:26, 1] = True, fz
    grown, _ = _freezes_grown(flags, dom, q, np.deg2rad(0.05))
    assert grown[20:35, 1].all()
    moving, _ = _freezes_grown(flags, dom, q, np.deg2rad(0.05), mean_q, np.deg2rad(0.05))
    assert moving[20:26, 1].all() and not moving[31:35, 1].any()
