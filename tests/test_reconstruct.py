"""analyses.reconstruct: sparse-marker reconstruction on synthetic periodic motions."""

from __future__ import annotations

import numpy as np
import pytest
from naive.knn import ckdtree_index_class

from mocapflow.framework import FeatureSet, Motion, MotionDatabase
from mocapflow.framework import quaternions as quat
from mocapflow.framework.joints import CANONICAL_JOINTS
from mocapflow.framework.testing import synthetic_skeleton
from mocapflow.plugins.similarity.applications.reconstruct import (
    PosePrior,
    PriorDatabase,
    ReconstructModel,
    ReconstructParams,
    joint_errors,
    local_poses,
    reconstruct_motion,
    reconstruct_positions,
    synthetic_markers,
)
from mocapflow.plugins.similarity.applications.retarget import positions_to_motion

CKDTreeIndex = ckdtree_index_class()


class EndEffectors15(FeatureSet):
    """Test stand-in for F_E^15: head, wrists, ankles in the root frame (15 dims)."""

    name = "fe15_test"
    joints = ("root", "lhip", "rhip", "head", "lwrist", "rwrist", "lankle", "rankle")

    @property
    def dim(self):
        return 15

    def transform_motion(self, motion):
        p = local_poses(motion.canonical_positions(self.joints), self.joints)
        return p[:, 3:].reshape(motion.n_frames, 15)


def periodic_motion(
    n_frames: int, t0: float = 0.0, amp: float = 1.0, yaw_deg: float = 0.0, name: str = "m", subject: str = "s"
) -> Motion:
    """A 1 Hz gait-like cycle: fixed per-joint sines, so every pose recurs each 30 frames."""
    sk = synthetic_skeleton()
    rng = np.random.default_rng(42)
    amp_j = rng.uniform(5, 35, (sk.n_joints, 3)) * amp
    phase = rng.uniform(0, 2 * np.pi, (sk.n_joints, 3))
    t = t0 + np.arange(n_frames) / 30.0
    ang = amp_j[None] * np.sin(2 * np.pi * t[:, None, None] + phase[None])
    ang[:, 0] *= 0.2  # a mostly upright root
    rot = quat.from_euler(ang, "zxy")
    yaw = quat.from_axis_angle(np.array([0.0, 1.0, 0.0]), np.deg2rad(yaw_deg))
    rot[:, 0] = quat.mul(np.broadcast_to(yaw, (n_frames, 4)), rot[:, 0])
    root = np.stack([0.5 * t, 0.95 + 0.02 * np.sin(4 * t), 0.2 * t], 1)
    return Motion(sk, root, rot, 30.0, name=name, metadata={"subject": subject})


@pytest.fixture(scope="module")
def prior_store():
    db = MotionDatabase(
        [
            periodic_motion(90, 0.0, name="a", subject="s1"),
            periodic_motion(60, 0.13, amp=0.9, name="b", subject="s1"),
            periodic_motion(60, 0.31, amp=1.1, name="c", subject="s2"),
        ]
    )
    return PriorDatabase(db, EndEffectors15())


def test_synthetic_markers_noise_within_bounds():
    m = periodic_motion(40)
    mk = synthetic_markers(m, noise=0.001, rng=np.random.default_rng(1))
    d = mk - m.canonical_positions(("root", "head", "lwrist", "rwrist", "lankle", "rankle"))
    assert mk.shape == (40, 6, 3) and np.abs(d).max() <= 0.001 and np.abs(d).max() > 0.0005


def test_joint_errors_against_loop():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(7, 4, 3)), rng.normal(size=(7, 4, 3))
    b[2, 1] = np.nan
    mean, mx, avg, worst = joint_errors(a, b)
    e = [[np.linalg.norm(a[t, j] - b[t, j]) * 100 for j in range(4)] for t in range(7)]
    assert mean[0] == pytest.approx(np.mean([r[0] for r in e]))
    assert mx[1] == pytest.approx(max(r[1] for i, r in enumerate(e) if i != 2))
    frame = [np.mean([v for v in r if np.isfinite(v)]) for r in e]
    assert avg == pytest.approx(np.mean(frame)) and worst == pytest.approx(max(frame))


def test_positions_to_motion_round_trip():
    m = periodic_motion(25, yaw_deg=70)
    pos = m.canonical_positions()
    out = positions_to_motion(m.skeleton, pos, CANONICAL_JOINTS, 30.0, name="x")
    assert np.abs(out.canonical_positions() - pos).max() < 1e-6
    assert np.allclose(np.linalg.norm(out.rotations, axis=-1), 1.0)
    one = positions_to_motion(m.skeleton, pos[:1], CANONICAL_JOINTS, 30.0)  # one-frame clip
    assert np.abs(one.canonical_positions() - pos[:1]).max() < 1e-6


def test_feature_map_exact_for_position_features(prior_store):
    prior = prior_store.prior(np.ones(3, bool), CKDTreeIndex())
    assert prior.feature_fit_r2 > 0.999999
    q = prior.query_features(prior.poses[17].astype(np.float64))
    assert np.abs(q[0] - prior.features[17]).max() < 1e-4


def test_reconstruction_between_database_poses_is_accurate(prior_store):
    # test poses lie half a frame between prior poses, seen under another heading and path
    test = periodic_motion(60, 0.5 / 30, yaw_deg=-120, name="t")
    prior = prior_store.prior(np.ones(3, bool), CKDTreeIndex())
    rec, e = reconstruct_motion(test, prior, ReconstructParams(k=16))
    assert e["avg_cm"] < 1.0 and e["max_frame_cm"] < 3.0
    assert rec.n_frames == 60 and rec.skeleton is test.skeleton and e["fk_avg_cm"] < e["avg_cm"] + 0.5
    # the markers alone placed on the nearest database pose of frame 0 do far worse
    world, heading = reconstruct_positions(synthetic_markers(test), prior, ReconstructParams(k=16))
    assert np.abs(np.angle(np.exp(1j * (heading - np.deg2rad(-120))))).max() < np.deg2rad(15)
    frozen = np.repeat(world[:1], 60, 0) - world[:1, :1] + world[:, :1]
    assert joint_errors(frozen, test.canonical_positions(prior.joints))[2] > 5 * e["avg_cm"]


def test_leave_out_and_unseen_amplitude(prior_store):
    test = periodic_motion(45, 0.2, amp=1.0, yaw_deg=30, name="a", subject="s1")
    assert prior_store.withheld(test, "clip").tolist() == [True, False, False]
    assert prior_store.withheld(test, "subject").tolist() == [True, True, False]
    assert not prior_store.withheld(test, "none").any()
    prior = prior_store.prior(~prior_store.withheld(test, "clip"), CKDTreeIndex())
    assert len(prior.poses) == 120
    _, e = reconstruct_motion(test, prior, ReconstructParams(k=24))
    assert e["avg_cm"] < 3.0  # interpolating between amplitudes 0.9 and 1.1


def test_input_validation(prior_store):
    prior = prior_store.prior(np.ones(3, bool), CKDTreeIndex())
    from mocapflow.framework import DataError

    with pytest.raises(DataError):
        reconstruct_positions(np.zeros((5, 4, 3)), prior)
    with pytest.raises(DataError):
        reconstruct_positions(np.zeros((5, 2, 3)), prior, model=ReconstructModel(markers=("head", "lwrist")))
    assert reconstruct_positions(np.zeros((0, 6, 3)), prior)[0].shape == (0, len(prior.joints), 3)
    m = periodic_motion(3, 0.5 / 30)
    for n in (1, 2, 3):  # one-frame clips and clips shorter than the backward pass
        world, _ = reconstruct_positions(synthetic_markers(m.slice(0, n)), prior, ReconstructParams(k=16))
        assert world.shape == (n, len(prior.joints), 3)
        assert joint_errors(world, m.slice(0, n).canonical_positions(prior.joints))[2] < 3.0
    with pytest.raises(DataError):
        PosePrior.build(np.zeros((1, 3)), np.zeros((1, 2)), CKDTreeIndex(), ("root",))


def test_pipeline_end_to_end(tmp_path):
    """pipelines/reconstruct.yaml on the bundled sample takes: motions, errors, BVH, tables."""
    from conftest import REPO

    from mocapflow.framework import Dataset, get_plugin_manager
    from mocapflow.framework.runner import run_pipeline

    run_pipeline(
        REPO / "pipelines" / "reconstruct.yaml", workspace=tmp_path, jobs=1, pm=get_plugin_manager(entry_points=False)
    )
    rec = Dataset(tmp_path / "reconstruction")
    clips = rec.table("clip_errors").to_pylist()
    assert sorted(c["name"] for c in clips) == ["02_01", "16_15"]
    assert all(0 < c["avg_cm"] < 10 and c["max_cm"] >= c["avg_cm"] and c["prior_frames"] < 656 for c in clips)
    db = rec.motions()
    assert sorted(m.name for m in db.motions) == ["02_01_recon", "16_15_recon"]
    assert sum(m.n_frames for m in db.motions) == sum(c["n_frames"] for c in clips)
    assert len(list((tmp_path / "bvh").glob("*.bvh"))) == 2
    t3 = Dataset(tmp_path / "evaluation").table("table3").to_pylist()
    assert {r["prior"] for r in t3} == {"CMU-", "CMU"}
    # the test subject's other takes help: leaving the subject out costs accuracy on average
    by = {p: np.mean([r["avg_cm"] for r in t3 if r["prior"] == p]) for p in ("CMU-", "CMU")}
    assert by["CMU"] <= by["CMU-"]
