from __future__ import annotations

import numpy as np
import pytest
from naive.kinematics import euler_matrix, fk_loop, forward_kinematics_numpy
from scipy.spatial.transform import Rotation
from synthetic import humanoid, random_motion

from mocapflow.framework import DataError, Motion, MotionDatabase, Skeleton
from mocapflow.framework import quaternions as quat
from mocapflow.framework.normalize import facing_angles, resample, to_root_frame
from mocapflow.plugins.relational.body import body_measures, rest_positions

ORDERS = ["xyz", "xzy", "yxz", "yzx", "zxy", "zyx"]


@pytest.mark.parametrize("order", ORDERS)
def test_euler_matches_explicit_matrices_and_inverts(order):
    rng = np.random.default_rng(1)
    ang = rng.uniform(-170, 170, size=(50, 3))
    ang[:, 1] = rng.uniform(-85, 85, size=50)  # keep away from gimbal lock for the inverse
    q = quat.from_euler(ang, order)
    for a, qq in zip(ang[:5], q[:5], strict=True):
        np.testing.assert_allclose(quat.to_matrix(qq), euler_matrix(a, order), atol=1e-12)
    back = quat.to_euler(q, order)
    np.testing.assert_allclose(back, ang, atol=1e-8)


def test_quaternion_algebra_against_scipy():
    rng = np.random.default_rng(2)
    a = quat.normalize(rng.normal(size=(100, 4)))
    b = quat.normalize(rng.normal(size=(100, 4)))
    v = rng.normal(size=(100, 3))
    ra, rb = Rotation.from_quat(np.roll(a, -1, axis=1)), Rotation.from_quat(np.roll(b, -1, axis=1))
    np.testing.assert_allclose(quat.rotate(a, v), ra.apply(v), atol=1e-12)
    np.testing.assert_allclose(quat.to_matrix(quat.mul(a, b)), (ra * rb).as_matrix(), atol=1e-12)
    m = quat.from_matrix(quat.to_matrix(a))
    np.testing.assert_allclose(np.abs(np.sum(m * a, axis=1)), 1.0, atol=1e-12)
    ang = quat.geodesic_angle(a, b)
    np.testing.assert_allclose(ang, (ra.inv() * rb).magnitude(), atol=1e-6)
    mid = quat.slerp(a, b, 0.5)
    np.testing.assert_allclose(quat.geodesic_angle(a, mid), ang / 2, atol=1e-6)


def test_fk_matches_per_frame_reference():
    m = random_motion(12, seed=3)
    ref = fk_loop(m.skeleton.parents, m.skeleton.offsets, m.root_translation, m.rotations)
    np.testing.assert_allclose(m.positions, ref, atol=1e-12)
    assert not m.positions.flags.writeable
    pos, glob = forward_kinematics_numpy(m.skeleton, m.root_translation, m.rotations)
    np.testing.assert_allclose(m.positions, pos, atol=1e-12)
    np.testing.assert_allclose(m.global_rotations, glob, atol=1e-12)


def test_fk_with_per_frame_translations_and_one_frame():
    m = random_motion(7, seed=8)
    rng = np.random.default_rng(0)
    lt = m.skeleton.offsets[None] + rng.normal(scale=0.01, size=(7, m.n_joints, 3))
    moved = m.with_arrays(local_translations=lt)
    ref = np.stack(
        [fk_loop(m.skeleton.parents, lt[t], m.root_translation[t : t + 1], m.rotations[t : t + 1])[0] for t in range(7)]
    )
    np.testing.assert_allclose(moved.positions, ref, atol=1e-12)
    one = m.slice(3, 4)
    np.testing.assert_allclose(one.positions[0], m.positions[3], atol=1e-12)
    empty = m.slice(0, 0)
    assert empty.positions.shape == (0, m.n_joints, 3)


def test_rest_pose_and_body_measures():
    sk = humanoid()
    rest = rest_positions(sk)
    assert rest[sk.index("lelbow"), 0] == pytest.approx(0.03 + 0.15 + 0.28)
    bm = body_measures(sk)
    assert bm["humerus_length"] == pytest.approx(0.28)
    assert bm["shoulder_width"] == pytest.approx(2 * (0.03 + 0.15))
    assert bm["hip_width"] == pytest.approx(0.2)
    assert bm["height"] == pytest.approx(0.05 + 0.84 + 0.1 + 0.36 + 0.08 + 0.18)


def test_root_frame_removes_position_and_heading():
    m = random_motion(40, seed=4)
    turn = quat.from_axis_angle(np.array([0.0, 1.0, 0.0]), 1.1)
    rot = m.rotations.copy()
    rot[:, 0] = quat.mul(np.broadcast_to(turn, rot[:, 0].shape), rot[:, 0])
    turned = m.with_arrays(rotations=rot, root_translation=m.root_translation + [5.0, 0.0, -3.0])
    a = to_root_frame(m.canonical_positions())
    b = to_root_frame(turned.canonical_positions())
    np.testing.assert_allclose(a, b, atol=1e-9)
    assert np.allclose(a[:, 0], 0.0)
    # after normalisation the hip axis points along +x: facing +z
    np.testing.assert_allclose(facing_angles(a), 0.0, atol=1e-9)


def test_resample_keeps_time_and_interpolates():
    m = random_motion(121, fps=120, seed=5)
    r = resample(m, 30)
    assert r.fps == 30 and r.n_frames == 31
    np.testing.assert_allclose(
        r.rotations[1], m.rotations[4] * np.sign(np.sum(r.rotations[1] * m.rotations[4], -1))[:, None], atol=1e-12
    )
    np.testing.assert_allclose(r.root_translation[-1], m.root_translation[-1])
    up = resample(m.slice(0, 3), 240)
    assert up.n_frames == 5
    np.testing.assert_allclose(up.root_translation[1], 0.5 * (m.root_translation[0] + m.root_translation[1]))
    assert r.metadata["source_fps"] == 120 and r.metadata["source_frames"] == 121


def test_one_frame_clip_and_database_ids():
    a, b = random_motion(1, seed=6), random_motion(5, seed=7)
    db = MotionDatabase([a, b], clip_ids=[10, 11])
    assert db.n_frames == 6 and list(db.offsets) == [0, 1, 6]
    clip, frame = db.frame_ids
    assert clip.tolist() == [10, 11, 11, 11, 11, 11] and frame.tolist() == [0, 0, 1, 2, 3, 4]
    pos, fr = db.locate(np.array([0, 1, 5]))
    assert pos.tolist() == [0, 1, 1] and fr.tolist() == [0, 0, 4]
    assert db.canonical_positions().shape == (6, 25, 3)
    assert resample(a, 10).n_frames == 1


def test_invalid_arrays_are_rejected():
    sk = humanoid()
    with pytest.raises(DataError):
        Motion(sk, np.zeros((3, 3)), np.zeros((3, 2, 4)), 30)
    with pytest.raises(DataError):
        Motion(sk, np.zeros((2, 3)), quat.identity((3, sk.n_joints)), 30)
    with pytest.raises(DataError):
        Skeleton(("a", "b"), np.array([-1, 1]), np.zeros((2, 3)))


def test_skeleton_serialisation_round_trip():
    sk = humanoid()
    again = Skeleton.from_dict(sk.to_dict())
    assert again == sk and again.fingerprint() == sk.fingerprint()
    assert again.canonical == sk.canonical


def test_chordal_mean_is_sign_invariant_and_central():
    rng = np.random.default_rng(9)
    centre = quat.normalize(rng.normal(size=4))
    axes = rng.normal(size=(50, 3))
    small = quat.from_axis_angle(axes / np.linalg.norm(axes, axis=1, keepdims=True), rng.uniform(0, 0.2, 50))
    samples = quat.mul(centre, small)
    flipped = np.where(rng.uniform(size=(50, 1)) < 0.5, -samples, samples)
    m = quat.chordal_mean(flipped)
    assert m[0] >= 0
    assert quat.geodesic_angle(m, centre) < 0.05
    np.testing.assert_allclose(quat.mean_of_outer(np.einsum("ni,nj->ij", samples, samples)), m, atol=1e-12)


def test_tables_round_trip_with_sparse_unsorted_clip_ids():
    """Clip ids are hashes (not sorted, not dense): frames are found by the clips table's
    order and frame counts, never by id rank."""
    from mocapflow.framework.motion_tables import database_from_tables, motions_to_tables

    ms = [random_motion(4, seed=1), random_motion(1, seed=2), random_motion(3, seed=3)]
    ids = [2_000_000_000, 7, 123_456]
    t = motions_to_tables(ms, ids)
    assert "positions" not in t["data"].column_names
    back = database_from_tables(t["clips"], t["skeletons"], t["data"], t["rotations"])
    assert back.clip_ids.tolist() == ids
    for m, r in zip(ms, back.motions, strict=True):
        np.testing.assert_allclose(r.root_translation, m.root_translation, atol=1e-5)
        np.testing.assert_allclose(r.positions, m.positions, atol=1e-4)
    with pytest.raises(DataError, match="distinct"):
        motions_to_tables(ms, [1, 1, 2])
