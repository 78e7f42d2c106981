"""Reconstruction onto any skeleton: the spine rule, composite bones, output on ASF/BVH rigs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mocapflow.framework import DataError, Motion, Skeleton
from mocapflow.framework import quaternions as quat
from mocapflow.plugins.similarity.applications.reconstruct_prior import (
    CONTROL_JOINTS,
    POSE_JOINTS,
    bone_parents,
    build_store,
    local_positions,
    pose_skeleton,
    spine_map,
)
from mocapflow.plugins.similarity.applications.retarget import positions_to_motion

REPO = Path(__file__).resolve().parents[3]
EXAMPLES = REPO / "examples" / "data" / "cmu"
CORPUS = REPO.parent / "shared" / "data"
if not CORPUS.is_dir():
    CORPUS = Path("/work/shared/data")


def rig(
    spine: tuple[float, ...],
    *,
    neck: bool = True,
    fingers: bool = True,
    toes: bool = True,
    wrists: bool = True,
    floor: bool = False,
    at_root: bool = False,
    names: dict[str, str] | None = None,
    clavicle: tuple[float, float] = (0.03, 0.08),
) -> Skeleton:
    """A synthetic rig whose spine has ``len(spine)`` bones of those lengths (the last joint
    is where the arms branch); only limbs, root, head and the extremities carry canonical
    names unless ``names`` (canonical -> joint name) adds some."""
    rows: list[tuple[str, str | None, tuple[float, float, float], str | None]] = []
    if floor:
        rows.append(("Floor", None, (0, 0, 0), None))
    rows.append(("Hips", "Floor" if floor else None, (0, 0.95, 0) if floor else (0, 0, 0), "root"))
    for s, x in (("L", 0.1), ("R", -0.1)):
        c = s.lower()
        rows += [
            (f"UpLeg{s}", "Hips", (x, -0.05, 0), f"{c}hip"),
            (f"Leg{s}", f"UpLeg{s}", (0, -0.42, 0), f"{c}knee"),
            (f"Foot{s}", f"Leg{s}", (0, -0.42, 0), f"{c}ankle"),
        ]
        if toes:
            rows.append((f"Toe{s}", f"Foot{s}", (0, -0.05, 0.12), f"{c}toes"))
    parent = "Hips"
    if at_root:
        rows.append(("Pelvis", "Hips", (0, 0, 0), None))
        parent = "Pelvis"
    for i, length in enumerate(spine):
        rows.append((f"Spine{i}", parent, (0, length, 0), None))
        parent = f"Spine{i}"
    chest = parent
    if neck:
        rows.append(("Neck", chest, (0, 0.12, 0), None))
    rows.append(("Head", "Neck" if neck else chest, (0, 0.1, 0), "head"))
    rows.append(("HeadTop", "Head", (0, 0.15, 0), "headtop"))
    for s, x in (("L", 1.0), ("R", -1.0)):
        c = s.lower()
        rows += [
            (f"Clav{s}", chest, (clavicle[0] * x, clavicle[1], 0), f"{c}clavicle"),
            (f"Arm{s}", f"Clav{s}", (0.15 * x, 0, 0), f"{c}shoulder"),
            (f"Fore{s}", f"Arm{s}", (0.28 * x, 0, 0), f"{c}elbow"),
        ]
        if wrists:
            rows.append((f"Hand{s}", f"Fore{s}", (0.25 * x, 0, 0), f"{c}wrist"))
            if fingers:
                rows.append((f"Fing{s}", f"Hand{s}", (0.09 * x, 0, 0), f"{c}fingers"))
    joint_names = [r[0] for r in rows]
    canonical = {r[3]: i for i, r in enumerate(rows) if r[3]}
    canonical.update({c: joint_names.index(n) for c, n in (names or {}).items()})
    parents = [-1 if r[1] is None else joint_names.index(r[1]) for r in rows]
    return Skeleton(tuple(joint_names), np.array(parents), np.array([r[2] for r in rows], float), canonical, name="rig")


def spine_names(sk: Skeleton) -> dict[str, str]:
    canon = spine_map(sk)
    return {j: sk.names[canon[j]] for j in ("lowerback", "upperback", "chest", "neck") if j in canon}


@pytest.mark.parametrize(
    "spine, want",
    [
        ((0.4,), {"chest": "Spine0"}),
        ((0.2, 0.2), {"upperback": "Spine0", "chest": "Spine1"}),
        ((0.1, 0.15, 0.25), {"upperback": "Spine1", "chest": "Spine2"}),
        ((0.1, 0.1, 0.1, 0.1), {"upperback": "Spine1", "chest": "Spine3"}),
    ],
)
def test_spine_rule_on_one_to_four_spine_bones(spine, want):
    """chest = where the arms branch; upperback = the joint nearest half the root->chest arc;
    neck = the joint between chest and head (none in a rig without one)."""
    assert spine_names(rig(spine)) == {**want, "neck": "Neck"}
    assert spine_names(rig(spine, neck=False)) == want


def test_spine_rule_keeps_consistent_dialect_names_and_fixes_others():
    # an ASF-like rig: a zero-length joint at the root is the lowerback; dialect names on the chain are kept
    sk = rig((0.12, 0.12), at_root=True, names={"upperback": "Spine1", "neck": "Neck"})
    assert spine_names(sk) == {"lowerback": "Pelvis", "upperback": "Spine1", "chest": "Spine1", "neck": "Neck"} or (
        spine_names(sk) == {"lowerback": "Pelvis", "upperback": "Spine0", "chest": "Spine1", "neck": "Neck"}
    )
    # a Mixamo-like dialect whose lowerback sits 10 cm up the spine: kept (the prior's
    # zero-length lowerback bones then point along the bone above, PriorStore.retarget)
    mixamo = rig((0.1, 0.12, 0.14), names={"lowerback": "Spine0", "upperback": "Spine1"})
    assert spine_names(mixamo) == {"lowerback": "Spine0", "upperback": "Spine1", "chest": "Spine2", "neck": "Neck"}
    # a PyMO-like dialect that calls the arms' branch joint "upperback": it is the chest
    pymo = rig((0.3,), neck=False, names={"upperback": "Spine0"})
    assert spine_names(pymo) == {"chest": "Spine0"}
    # a floor joint above the root (Bandai-Namco joint_Root) is no spine joint
    assert spine_names(rig((0.2, 0.2), floor=True)) == {"upperback": "Spine0", "chest": "Spine1", "neck": "Neck"}


def test_pose_joints_without_fingers_or_toes_and_missing_control_points():
    sk, joints = pose_skeleton(rig((0.2, 0.2), fingers=False, toes=False))
    assert set(joints) == set(POSE_JOINTS) - {"lfingers", "rfingers", "ltoes", "rtoes", "lowerback"}
    assert list(joints) == [j for j in POSE_JOINTS if j in joints] and sk.canonical["chest"] == sk.names.index("Spine1")
    with pytest.raises(DataError, match=r"no joint for \['lwrist', 'rwrist'\].*control points"):
        pose_skeleton(rig((0.2, 0.2), wrists=False))
    assert set(CONTROL_JOINTS) <= set(joints)


def moving(sk: Skeleton, n: int = 40, seed: int = 0, name: str = "m") -> Motion:
    """Smoothly varying rotations of every joint (up to ~25 degrees) on ``sk``."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 30.0
    amp, ph = rng.uniform(5, 25, (sk.n_joints, 3)), rng.uniform(0, 6.3, (sk.n_joints, 3))
    ang = amp[None] * np.sin(2 * np.pi * t[:, None, None] + ph[None])
    root = np.stack([0.3 * t, 0.95 + 0 * t, 0.1 * t], 1)
    return Motion(sk, root, quat.from_euler(ang, "zxy"), 30.0, name=name, metadata={"subject": name})


def test_composite_bones_point_along_the_prior_takes_own_joints(tmp_path):
    """A prior seen on a subset of its joints (a 1-bone spine, no neck, fingers or toes):
    every composite bone of a retargeted pose points where the take's own joints do (loop twin)."""
    take = moving(rig((0.12, 0.12), at_root=True, names={"upperback": "Spine0", "neck": "Neck"}), seed=1)
    store = build_store([take], mirrored=False)
    assert store.joints == POSE_JOINTS and store.lengths is not None
    sub = tuple(j for j in POSE_JOINTS if j not in ("lowerback", "upperback", "neck", "lfingers", "rtoes"))
    view = store.on_joints(sub)
    poses = view.retarget(np.ones(len(sub)))  # unit bones: each bone's vector is its direction
    par = bone_parents(sub)
    own = local_positions(take.with_arrays(skeleton=pose_skeleton(take.skeleton)[0]).canonical_positions(sub), sub)
    for t in range(0, take.n_frames, 7):
        for j in range(1, len(sub)):
            v = own[t, j] - own[t, par[j]]
            np.testing.assert_allclose(poses[t, j] - poses[t, par[j]], v / np.linalg.norm(v), atol=1e-5)
    assert store.on_joints(POSE_JOINTS).tree is None  # the full set is the store itself
    # saved and loaded with its take lengths; a store written without them uses REFERENCE_LENGTHS
    from dataclasses import replace

    from mocapflow.plugins.similarity.applications.reconstruct_prior import PriorStore

    back = PriorStore.load(store.save(Path(tmp_path) / "prior"))
    np.testing.assert_array_equal(back.lengths, store.lengths)
    old = replace(store, lengths=None).on_joints(sub).retarget(np.ones(len(sub)))
    steps = np.linalg.norm(old[:, 1:] - old[:, par[1:]], axis=-1)
    assert np.isfinite(old).all() and np.allclose(steps[steps > 0.5], 1.0, atol=1e-5)
    with pytest.raises(DataError, match="not in the prior"):
        build_store([take], joints=sub).on_joints(POSE_JOINTS)


def test_clavicles_start_where_the_served_rig_has_them():
    """A prior of a rig whose clavicles start at the neck's place, seen by a rig whose
    clavicles start a hand's width apart: in every retargeted pose the clavicle bone keeps
    the served rig's angle to the chest -> neck bone and sits on its side."""
    cmu_like = rig((0.12, 0.12), at_root=True, names={"upperback": "Spine0", "neck": "Neck"}, clavicle=(0.0, 0.12))
    store = build_store([moving(cmu_like, seed=2)], mirrored=False)
    other = rig((0.15, 0.1), clavicle=(0.05, 0.1))  # a Bandai-like chest: clavicles 5 cm each side
    sk, joints = pose_skeleton(other)
    rest = Motion(sk, np.zeros((1, 3)), np.tile([1.0, 0, 0, 0], (1, sk.n_joints, 1)), 30.0).canonical_positions(joints)[
        0
    ]
    lengths = np.linalg.norm(rest - rest[np.maximum(bone_parents(joints), 0)], axis=1)
    poses = store.on_joints(joints, rest).retarget(lengths)
    plain = store.on_joints(joints).retarget(lengths)
    c, n, lc, rc = (joints.index(j) for j in ("chest", "neck", "lclavicle", "rclavicle"))

    def angle(p: np.ndarray, a: int, b: int) -> np.ndarray:
        u, v = p[:, a] - p[:, c], p[:, b] - p[:, c]
        cos = (u * v).sum(-1) / np.linalg.norm(u, axis=-1) / np.linalg.norm(v, axis=-1)
        return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))

    want = angle(rest[None], n, lc)[0]
    np.testing.assert_allclose(angle(poses, n, lc), want, atol=1e-3)
    np.testing.assert_allclose(angle(poses, n, rc), want, atol=1e-3)
    assert want > 15 and angle(plain, n, lc).max() < 5  # without the rig: along the neck, as the prior's rig
    side = np.cross(
        poses[:, n] - poses[:, c], poses[:, joints.index("lshoulder")] - poses[:, joints.index("rshoulder")]
    )
    lat = poses[:, lc] - poses[:, rc]
    assert (np.einsum("nc,nc->n", np.cross(poses[:, n] - poses[:, c], lat), side) > 0).all()


def test_takes_lacking_a_pose_joint_stay_out_of_the_prior():
    one_bone = moving(rig((0.3,), neck=False), name="pymo_like")
    with pytest.raises(DataError, match="no prior take"):
        build_store([one_bone], mirrored=False)


def test_output_on_a_rig_with_a_floor_joint_and_intermediate_joints():
    """positions_to_motion on a root below joint 0: the canonical joints land on their
    targets and the floor joint keeps its rest rotation; with unnamed spine joints (aimed
    through, so a bent spine is met only approximately) the limb ends still reach theirs."""
    sk, joints = pose_skeleton(rig((0.2, 0.2), floor=True))
    m = moving(sk, seed=3)
    out = positions_to_motion(sk, m.canonical_positions(joints), joints, m.fps)
    err = np.linalg.norm(out.canonical_positions(joints) - m.canonical_positions(joints), axis=-1)
    assert err.max() < 1e-6
    np.testing.assert_allclose(out.rotations[:, 0], np.tile([1.0, 0, 0, 0], (m.n_frames, 1)), atol=1e-9)
    sk, joints = pose_skeleton(rig((0.1, 0.1, 0.1, 0.1), floor=True))
    m = moving(sk, seed=3)
    out = positions_to_motion(sk, m.canonical_positions(joints), joints, m.fps)
    err = np.linalg.norm(out.canonical_positions(joints) - m.canonical_positions(joints), axis=-1)
    ends = [joints.index(j) for j in ("root", "lwrist", "rwrist", "lankle", "rankle")]
    assert err[:, ends].max() < 1e-3 and err.max() < 0.05 and err.mean() < 0.005


def test_two_bone_middle_matches_the_reconstruction_limb_ik():
    """The output's vectorised two-bone IK against the per-frame limb_ik of the solve (twin)."""
    from mocapflow.plugins.similarity.applications.reconstruct import _Frames, limb_ik
    from mocapflow.plugins.similarity.applications.retarget import two_bone_middle

    rng = np.random.default_rng(7)
    base, end, hint = rng.normal(0, 0.3, (3, 50, 3))
    end[:5] = base[:5] + [0.9, 0.0, 0.0]  # out of reach
    l1, l2 = 0.3, 0.25
    fast = two_bone_middle(base, end, hint, l1, l2)
    fr = _Frames(np.zeros(0, int), np.zeros(0, int), np.array([-1, 0, 1]), np.eye(3), np.array([0.0, l1, l2]), [])
    fr.limbs = [(0, 1, 2, 0, np.zeros(0, int))]
    for t in range(50):
        pose = np.stack([base[t], hint[t], hint[t] + [0.0, 0.1, 0.0]]).ravel()
        want = limb_ik(pose, end[t][None], fr).reshape(3, 3)[1]
        np.testing.assert_allclose(fast[t], want, atol=1e-7)
    assert np.allclose(np.linalg.norm(fast - base, axis=1), l1)


def test_amc_output_honours_the_asf_dofs(tmp_path):
    """On a CMU ASF skeleton (hinge elbows/knees, two-dof clavicles, dof-less hip joints) the
    take written as AMC and read back puts the canonical joints where the take had them."""
    from mocapflow.plugins.formats.asf_amc import read_amc, write_amc

    take = read_amc(EXAMPLES / "16" / "16_15.amc").slice(0, 60)
    sk, joints = pose_skeleton(take.skeleton)
    want = take.canonical_positions(joints)
    out = positions_to_motion(sk, want, joints, take.fps, name="x")
    write_amc(out, tmp_path / "x.amc")
    from mocapflow.plugins.formats._asf import write_asf

    write_asf(out.skeleton, tmp_path / "x.asf")
    back = read_amc(tmp_path / "x.amc")
    err = np.linalg.norm(back.canonical_positions(joints) - want, axis=-1) * 100
    assert err.mean() < 0.2 and err.max() < 3.0, (err.mean(), err.max())


@pytest.fixture(scope="module")
def prior_folder(tmp_path_factory):
    from mocapflow.framework.normalize import resample
    from mocapflow.plugins.formats.asf_amc import read_amc

    takes = [resample(read_amc(f), 30.0) for f in sorted(EXAMPLES.glob("*/*.amc"))]
    return build_store(takes).save(tmp_path_factory.mktemp("skel") / "prior")


def corpus_take(pattern: str) -> Path:
    files = sorted(CORPUS.glob(pattern))
    if not files:
        pytest.skip(f"corpus not present: no {pattern} under {CORPUS}")
    return min(files, key=lambda p: p.stat().st_size)


@pytest.mark.parametrize("pattern", ["bvh/bandai_namco_1/*.bvh", "bvh/xia_style/*.bvh"])
def test_cli_reconstructs_a_bandai_and_a_xia_take_on_its_own_skeleton(tmp_path, prior_folder, pattern):
    from mocapflow.framework.cli import main
    from mocapflow.plugins.formats.bvh import read_bvh

    src = corpus_take(pattern)
    out = tmp_path / "out.bvh"
    assert main(["reconstruct", str(src), "--prior", str(prior_folder), "-o", str(out), "-k", "16"]) == 0
    take, rec = read_bvh(src), read_bvh(out)
    assert rec.skeleton.names == take.skeleton.names and rec.n_frames == take.n_frames
    ends = ("root", "head", "lwrist", "rwrist", "lankle", "rankle")
    err = np.linalg.norm(rec.canonical_positions(ends) - take.canonical_positions(ends), axis=-1) * 100
    assert np.median(err) < 2.0 and err.mean() < 4.0, (np.median(err), err.mean())


def test_cli_names_a_missing_wrist(tmp_path, prior_folder, capsys):
    from mocapflow.framework.cli import main
    from mocapflow.plugins.formats._bvh_write import write_bvh

    sk = rig((0.2, 0.2), wrists=False)
    write_bvh(moving(sk, n=5), tmp_path / "nowrist.bvh")
    code = main(
        ["reconstruct", str(tmp_path / "nowrist.bvh"), "--prior", str(prior_folder), "-o", str(tmp_path / "o.bvh")]
    )
    assert code != 0
    msg = capsys.readouterr().err
    assert "lwrist" in msg and "Traceback" not in msg
