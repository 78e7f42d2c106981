"""The freeze cue on holds and the hold fill of the calibrated cleaner, against slow
references (tests/naive/cleaning_holds.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
from naive.cleaning import synthetic_walk
from naive.cleaning_holds import naive_consensus_fill, naive_hold_lengths

from mocapflow.framework import quaternions as quat
from mocapflow.plugins.selfsim.calibrated import cues, holds
from mocapflow.plugins.selfsim.calibrated.constants import CUES, HOLD_SPEED
from mocapflow.plugins.selfsim.cleaner import MDMCleaner, clean_motion
from mocapflow.plugins.selfsim.evaluation.error_injection import apply_error


def _track(n: int, axis=(0.3, 1.0, -0.2), rate: float = 0.05) -> np.ndarray:
    """A joint turning at a constant rate about one axis, (n, 4)."""
    ax = np.asarray(axis, float) / np.linalg.norm(axis)
    return quat.from_axis_angle(np.broadcast_to(ax, (n, 3)), rate * np.arange(n))


def test_hold_lengths_match_the_naive_reference():
    rng = np.random.default_rng(0)
    v = rng.uniform(0.002, 0.01, (40, 5))
    v[5:14, 0] = 0.0  # a hold in the middle
    v[:6, 1] = 0.0  # a hold from the first frame
    v[33:, 2] = 0.0  # a hold to the last frame
    v[20, 3] = 0.0  # one still step: two held frames
    length, edge = cues.hold_lengths(v, HOLD_SPEED)
    n_length, n_edge = naive_hold_lengths(v, HOLD_SPEED)
    np.testing.assert_array_equal(length, n_length)
    np.testing.assert_array_equal(edge, n_edge)
    assert length[5, 0] == 10 and not edge[5, 0] and edge[0, 1] and edge[-1, 2] and length[20, 3] == 2


def test_freeze_cue_counts_only_on_holds():
    t = 30
    frozen = np.zeros((t, 2))
    cue = {
        "digression": np.full((t, 2), 0.1),
        "acceleration": np.zeros((t, 2)),
        "expected_acc": np.zeros((t, 2)),
        "mirror": np.zeros((t, 2)),
        "held_freeze": np.full((t, 2), 3.0),
        "hold": frozen,
    }
    cue["hold"][10:22, 0] = 12.0  # joint 0 held for 12 frames; joint 1 slow but moving
    scale = {"digression": np.full(2, 0.1), "acceleration": np.ones(2)}
    frz = cues.cue_values(cue, scale)[..., CUES.index("freeze")]
    assert np.all(frz[10:22, 0] == 3.0) and frz[:10, 0].max() == 0.0 and frz[:, 1].max() == 0.0


def test_fills_match_references_and_restore_what_they_can():
    track = _track(40)
    bad = track.copy()
    bad[10:24] = track[10]  # frozen from frame 10 to 23, moving again at 24
    mean = quat.normalize(track + 0.02 * np.random.default_rng(1).standard_normal(track.shape))
    got = holds.consensus_fill(bad, mean, 10, 24)
    np.testing.assert_allclose(np.abs(np.sum(got * naive_consensus_fill(bad, mean, 10, 24), -1)), 1.0, atol=1e-9)
    # with the clean track as the consensus the fill restores it exactly
    np.testing.assert_allclose(
        np.abs(np.sum(holds.consensus_fill(bad, track, 10, 24) * track[11:24], -1)), 1.0, atol=1e-9
    )


def test_fill_holds_fills_flagged_and_frozen_interior_holds_only():
    t = 60
    q = np.stack([_track(t, rate=0.04), _track(t, axis=(1, 0, 0), rate=0.03), _track(t, rate=0.02)], axis=1)
    bad = q.copy()
    bad[20:35, 0] = q[20, 0]  # an interior hold, flagged
    bad[40:52, 1] = q[40, 1]  # an interior hold, not flagged: the consensus turns 19 degrees, the joint jumps out
    bad[:12, 2] = q[11, 2]  # a hold from the first frame: one side only
    seeds = np.zeros((t, 3), bool)
    seeds[25, 0] = seeds[45, 2] = seeds[5, 2] = True
    out, filled, held = holds.fill_holds(bad, seeds, 8, q)
    assert filled[21:35, 0].all() and not filled[20, 0] and held[20:35, 0].all()
    assert filled[41:52, 1].all() and filled.sum() == 14 + 11 and not filled[:, 2].any()
    np.testing.assert_array_equal(out[:, 2], bad[:, 2])
    for c, (a, b) in ((0, (21, 35)), (1, (41, 52))):
        assert quat.geodesic_angle(out[a:b, c], q[a:b, c]).max() < 1e-6
    # a still consensus: the unflagged hold is the motion's own and stays
    still = q.copy()
    still[:, 1] = q[40, 1]
    _, filled2, _ = holds.fill_holds(bad, seeds, 8, still)
    assert not filled2[:, 1].any()


def test_calibrated_cleaner_fills_a_frozen_joint():
    clean = synthetic_walk(240, seed=5, name="take")
    rot = clean.rotations.copy()
    j = clean.skeleton.canonical["lknee"]
    apply_error(rot, clean, "freeze", 100, 118, [j], 0.0, np.random.default_rng(0))
    bad = clean.with_arrays(rotations=rot, name="take")
    context = [synthetic_walk(240, seed=s, name=f"ctx{s}") for s in (6, 7)]
    cleaner = MDMCleaner(write_bvh=False, heatmaps=False)
    fitted = cleaner.clean(bad, context).calibration
    # on these synthetic walks the other cues already find every calibration error, so the greedy
    # allocation leaves the freeze cue unused: given a weight, it finds and fills the hold
    weights = fitted.weights.copy()
    weights[CUES.index("freeze")] = 1.0
    out = clean_motion(cleaner, bad, context, calibration=dataclasses.replace(fitted, weights=weights))
    c = out.analysis.joints.index("lknee")
    err0 = quat.geodesic_angle(bad.rotations[100:118, j], clean.rotations[100:118, j])
    err1 = quat.geodesic_angle(out.cleaned.rotations[100:118, j], clean.rotations[100:118, j])
    assert out.flags[100:118, c].any() and set(out.cue[100:118, c][out.flags[100:118, c]]) == {"freeze"}
    assert (err1**2).sum() < 0.5 * (err0**2).sum()
