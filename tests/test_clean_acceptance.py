"""Per-run checks of the calibrated repair (issue 14, session 5): edits bounded by the
evidence, runs kept only on a consensus gain above the clean scatter, freeze growth only where
the consensus moves."""
from __future__ import annotations

import numpy as np
from naive.cleaning import synthetic_walk
from naive.cleaning_acceptance import naive_accept_runs

from mocapflow.framework import quaternions as quat
from mocapflow.plugins.selfsim.run_acceptance import accept_runs, edit_runs, shrink_weak_runs


def _rot(q, deg, axis=(0.0, 0.6, 0.8)):
    return quat.mul(q, quat.from_axis_angle(np.asarray(axis), np.deg2rad(deg)))


def _walk(n=40, m=3):
    return quat.make_continuous(synthetic_walk(n, seed=2).rotations, axis=0)[:, :m].copy()


def test_edit_runs_split_per_joint_and_skip_excluded_cells():
    edited = np.zeros((10, 2), bool)
    edited[2:5, 0] = edited[7, 0] = edited[1:9, 1] = True
    exclude = np.zeros((10, 2), bool)
    exclude[4:6, 1] = True
    assert edit_runs(edited, exclude) == [(0, 2, 5), (0, 7, 8), (1, 1, 4), (1, 6, 9)]


def test_weak_runs_are_moved_in_proportion_to_their_evidence():
    q = _walk()
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


def test_runs_are_kept_only_on_a_gain_above_the_clean_scatter_as_the_naive_reference():
    rng = np.random.default_rng(4)
    q = _walk(50, 4)
    mean_q = _rot(q, 6.0)  # the consensus: 6 degrees from the take everywhere
    new = q.copy()
    edited = rng.random((50, 4)) < 0.3
    deg = rng.uniform(1.0, 6.0, size=(50, 4))
    toward = quat.slerp(q, mean_q, deg / 6.0)
    new[edited] = toward[edited]
    exclude = rng.random((50, 4)) < 0.1
    typical = np.deg2rad(np.array([2.0, 4.0, 5.0, 3.0]))
    for margin in (0.0, 1.0, 3.0):
        out, undone = accept_runs(q, new, mean_q, edited, exclude, typical, margin)
        ref = naive_accept_runs(q, new, mean_q, edited, exclude, typical, margin)
        np.testing.assert_allclose(out, ref, atol=1e-9)
        assert np.array_equal(out[exclude], new[exclude])
    assert accept_runs(q, new, mean_q, edited, exclude, typical, 0.0)[1] == 0  # every run moved nearer
    assert accept_runs(q, new, mean_q, edited, exclude, typical, 100.0)[1] == len(edit_runs(edited, exclude))


def test_freeze_growth_stops_where_the_consensus_is_still_too():
    from mocapflow.plugins.selfsim.cues import CUES
    from mocapflow.plugins.selfsim.decision import _freezes_grown

    q = _walk(60)
    q[20:35, 1] = q[20, 1]  # joint 1 still over frames 20-34
    mean_q = q.copy()
    mean_q[20:35, 1] = _walk(60)[20:35, 1]  # the consensus moves on ...
    mean_q[28:35, 1] = mean_q[28, 1]  # ... then holds still from frame 28
    fz = CUES.index("freeze")
    flags = np.zeros((60, 3), bool)
    dom = np.full((60, 3), CUES.index("digression"))
    flags[24:26, 1], dom[24:26, 1] = True, fz
    grown, _ = _freezes_grown(flags, dom, q, np.deg2rad(0.05))
    assert grown[20:35, 1].all()
    moving, _ = _freezes_grown(flags, dom, q, np.deg2rad(0.05), mean_q, np.deg2rad(0.05))
    assert moving[20:26, 1].all() and not moving[31:35, 1].any()


def test_unclaimed_short_runs_are_left_as_they_were():
    from types import SimpleNamespace

    from mocapflow.plugins.selfsim.decision import _run_checks

    q = _walk(30, 3)
    new = q.copy()
    new[5, 0] = _rot(q[5, 0], 5.0)  # one frame, below flag_min_deg: no claim
    new[10:13, 1] = _rot(q[10:13, 1], 5.0)  # three frames, no claim
    new[20, 2] = _rot(q[20, 2], 20.0)  # a claim
    p = SimpleNamespace(shrink_full=None, accept_margin=None, unclaimed_revert=True, flag_min_deg=10.0,
                        unclaimed_frames=2)
    res = SimpleNamespace(texture=SimpleNamespace(q=q), mean_texture=q)
    none = np.zeros((30, 3), bool)
    out, edited = _run_checks(p, res, None, new, none, np.zeros((30, 3)), np.zeros((30, 3), int), none, none)
    assert not edited[5, 0] and edited[10:13, 1].all() and edited[20, 2] and edited.sum() == 4
    p.unclaimed_frames = None
    out, edited = _run_checks(p, res, None, new, none, np.zeros((30, 3)), np.zeros((30, 3), int), none, none)
    assert edited.sum() == 1 and np.array_equal(out[:, :2], q[:, :2])
