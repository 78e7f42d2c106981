"""The freeze cue on holds and the hold fill of the calibrated cleaner, against slow
references (tests/naive/cleaning_holds.py)."""

from __future__ import annotations

import numpy as np
from naive.cleaning_holds import naive_consensus_fill, naive_hold_lengths

from mocapflow.framework import quaternions as quat
from mocapflow.plugins.selfsim.calibrated import cues, holds
from mocapflow.plugins.selfsim.calibrated.constants import HOLD_SPEED


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


def test_hold_detector_sees_interior_holds_where_the_consensus_moves():
    from mocapflow.plugins.selfsim.calibrated.detectors import DETECTORS, evidence

    t = 60
    q = np.stack([_track(t, rate=0.04), _track(t, axis=(1, 0, 0), rate=0.03)], axis=1)
    bad = q.copy()
    bad[20:35, 0] = q[20, 0]  # joint 0 frozen while its consensus (the clean track) turns
    still = q.copy()
    still[:, 1] = q[0, 1]  # joint 1 still in the take and in its consensus: the motion's own
    bad[:, 1] = still[:, 1]
    ev = evidence(bad, still, None, ["a", "b"])[..., DETECTORS.index("hold")]
    assert ev[21:34, 0].min() > 1.0 and ev[:19, 0].max() == 0.0 and ev[:, 1].max() == 0.0


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


def test_repair_fills_a_hold_flagged_run_from_the_consensus():
    from types import SimpleNamespace

    from mocapflow.plugins.selfsim.calibrated.bounded_repair import repair_flagged
    from mocapflow.plugins.selfsim.calibrated.detectors import DETECTORS

    t = 60
    q = np.stack([_track(t, rate=0.04), _track(t, axis=(1, 0, 0), rate=0.03)], axis=1)
    bad = q.copy()
    bad[20:35, 0] = q[20, 0]
    res = SimpleNamespace(
        texture=SimpleNamespace(q=bad), mean_texture=q, spread=np.zeros((t, 2)), joints=("a", "b"), neighbours=[]
    )
    flags = np.zeros((t, 2), bool)
    flags[25:28, 0] = True  # the test fired inside the hold
    det = np.full((t, 2), DETECTORS.index("hold"))
    new, edited = repair_flagged(res, flags, det, flags.astype(float))
    assert edited[21:35, 0].all() and not edited[:20].any() and not edited[36:].any() and not edited[:, 1].any()
    assert quat.geodesic_angle(new[21:35, 0], q[21:35, 0]).max() < 1e-6
    # nothing flagged: nothing repaired
    assert not repair_flagged(res, np.zeros((t, 2), bool), det, np.zeros((t, 2)))[1].any()
