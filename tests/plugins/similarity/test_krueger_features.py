"""features.end_effectors and features.pca (Krüger et al. 2010 §3)."""

from __future__ import annotations

import numpy as np
import pytest
from naive.features import end_effector_features

from mocapflow.framework import MotionDatabase
from mocapflow.framework import quaternions as quat
from mocapflow.framework.errors import DataError
from mocapflow.framework.testing import synthetic_motion, synthetic_skeleton
from mocapflow.plugins.similarity.knn.end_effectors import JOINT_SETS, EndEffectorFeatures
from mocapflow.plugins.similarity.knn.pca import PosePCA


def _tpose(n=3, heading_deg=0.0, root=(1.0, 0.95, -2.0)):
    from mocapflow.framework import Motion

    sk = synthetic_skeleton()
    rot = quat.identity((n, sk.n_joints))
    rot[:, 0] = quat.from_axis_angle(np.array([0.0, 1.0, 0.0]), np.radians(heading_deg))
    return Motion(sk, np.tile(root, (n, 1)), rot, 30.0, name="tpose")


@pytest.mark.parametrize("heading", [0.0, 73.0, -150.0])
def test_tpose_end_effectors_are_known(heading):
    x = EndEffectorFeatures(joints=5).transform(_tpose(heading_deg=heading))
    # synthetic humanoid: wrists at x = ±(0.03+0.15+0.28+0.25), y = 0.1+0.12+0.12+0.08 above the root;
    # ankles at ±0.1, -0.05-0.84; head at 0.1+0.12+0.12+0.12+0.08
    arm_y = 0.1 + 0.12 + 0.12 + 0.08
    want = np.array([[0.71, arm_y, 0], [-0.71, arm_y, 0], [0.1, -0.89, 0], [-0.1, -0.89, 0], [0, 0.54, 0]])
    np.testing.assert_allclose(x.reshape(-1, 5, 3), np.broadcast_to(want, (3, 5, 3)), atol=1e-6)


@pytest.mark.parametrize("joints,samples", [(5, 1), (10, 1), (13, 1), (5, 3), (5, 5), (10, 3)])
def test_matches_naive_reference(joints, samples):
    m = synthetic_motion(25, fps=30.0, seed=joints + samples)
    fs = EndEffectorFeatures(joints=joints, samples=samples)
    x = fs.transform(m)
    assert x.dtype == np.float32 and x.shape == (25, fs.dim) and fs.dim == 3 * joints * samples
    ref = end_effector_features(m, JOINT_SETS[joints], samples, 0.3)
    np.testing.assert_allclose(x, ref, atol=2e-6)


def test_window_is_in_seconds_and_clamped_at_clip_edges():
    m30 = synthetic_motion(40, fps=30.0, seed=3)
    fs = EndEffectorFeatures(joints=5, samples=3)
    x = fs.transform(m30).reshape(40, 3, 15)
    pose = EndEffectorFeatures(joints=5).transform(m30)
    np.testing.assert_allclose(x[:, 1], pose, atol=1e-6)  # centre sample = the frame itself
    np.testing.assert_allclose(x[0, 0], pose[0], atol=1e-6)  # clamped: no frame before the clip
    np.testing.assert_allclose(x[-1, 2], pose[-1], atol=1e-6)
    np.testing.assert_allclose(x[10, 0], 0.5 * (pose[5] + pose[6]), atol=1e-6)  # t - 4.5 frames at 30 Hz
    # a one-frame clip and a database: windows never read the neighbouring clip
    one = synthetic_motion(1, seed=9)
    db = MotionDatabase([m30, one, m30])
    xd = fs.transform(db)
    np.testing.assert_array_equal(xd[40], np.tile(EndEffectorFeatures(joints=5).transform(one)[0], 3))
    np.testing.assert_array_equal(xd[41:], fs.transform(m30))


def test_missing_joint_is_a_data_error():
    from mocapflow.framework import Motion, Skeleton

    sk = synthetic_skeleton()
    canon = {k: v for k, v in sk.canonical.items() if k != "lowerback"}
    sk2 = Skeleton(sk.names, sk.parents, sk.offsets, canonical=canon, name="nolowerback")
    m = Motion(sk2, np.zeros((2, 3)), quat.identity((2, sk.n_joints)), 30.0)
    EndEffectorFeatures(joints=10).transform(m)
    with pytest.raises(DataError, match="lowerback"):
        EndEffectorFeatures(joints=13).transform(m)


def test_pca_fit_persist_and_reuse(tmp_path):
    db = MotionDatabase([synthetic_motion(80, seed=s) for s in range(3)])
    pca = PosePCA(n_components=8).fit(db)
    c = pca.components_
    np.testing.assert_allclose(c @ c.T, np.eye(8), atol=1e-10)
    x = pca.transform(db)
    assert x.shape == (240, 8) and x.dtype == np.float32
    # centred scores, variances descending, and a full-rank PCA reproduces the poses exactly
    np.testing.assert_allclose(x.mean(0), 0, atol=1e-5)
    assert np.all(np.diff(x.var(0)) <= 1e-6)
    full = PosePCA(n_components=54).fit(db)
    back = full.transform(db).astype(np.float64) @ full.components_ + full.mean_
    np.testing.assert_allclose(back, np.concatenate([full._poses(m) for m in db.motions]), atol=1e-5)
    pca.save_state(tmp_path)
    again = PosePCA(n_components=8).load_state(tmp_path)
    np.testing.assert_array_equal(again.transform(db), x)
    fewer = PosePCA(n_components=4).load_state(tmp_path)
    np.testing.assert_array_equal(fewer.transform(db), x[:, :4])
    with pytest.raises(DataError):
        PosePCA(n_components=16).load_state(tmp_path)
    with pytest.raises(DataError):
        PosePCA().transform(db)
