"""analyses.reconstruct: sparse-marker reconstruction on synthetic periodic motions."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.framework import DataError, Motion, Skeleton
from mocapflow.framework import quaternions as quat
from mocapflow.framework.joints import CANONICAL_JOINTS
from mocapflow.framework.normalize import rotate_about_y
from mocapflow.framework.testing import synthetic_skeleton
from mocapflow.plugins.similarity.applications.reconstruct import (
    PosePrior,
    ReconstructModel,
    ReconstructParams,
    _local_model,
    _yaw_align,
    reconstruct_positions,
)
from mocapflow.plugins.similarity.applications.reconstruct_prior import (
    POSE_JOINTS,
    PriorStore,
    bone_lengths,
    bone_parents,
    build_store,
    directions,
    local_positions,
    mirror,
)
from mocapflow.plugins.similarity.applications.reconstruct_synthetic import (
    PriorCache,
    joint_errors,
    reconstruct_motion,
    synthetic_markers,
    withheld,
)
from mocapflow.plugins.similarity.applications.retarget import positions_to_motion


def scaled_skeleton(scale: float) -> Skeleton:
    sk = synthetic_skeleton()
    return Skeleton(sk.names, sk.parents, sk.offsets * scale, canonical=dict(sk.canonical), name=f"synthetic_x{scale}")


def periodic_motion(
    n_frames: int,
    t0: float = 0.0,
    amp: float = 1.0,
    yaw_deg: float = 0.0,
    name: str = "m",
    subject: str = "s",
    scale: float = 1.0,
) -> Motion:
    """A 1 Hz gait-like cycle: fixed per-joint sines, so every pose recurs each 30 frames."""
    sk = scaled_skeleton(scale)
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
def store():
    """Prior takes of a performer 15 % larger than the test performers (mirror images too)."""
    return build_store(
        [
            periodic_motion(90, 0.0, name="a", subject="s1", scale=1.15),
            periodic_motion(60, 0.13, amp=0.9, name="b", subject="s1", scale=1.15),
            periodic_motion(60, 0.31, amp=1.1, name="c", subject="s2", scale=1.15),
        ]
    )


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


def test_store_layout_and_mirror(store):
    assert [c["name"] for c in store.clips] == ["a", "a", "b", "b", "c", "c"]
    assert [c["mirrored"] for c in store.clips] == [False, True] * 3
    assert store.n_frames == 2 * 210 and store.clip_rows.tolist() == [0, 90, 180, 240, 300, 360, 420]
    assert np.allclose(np.linalg.norm(store.dirs[:, 1:], axis=-1), 1.0, atol=1e-5)
    m = periodic_motion(10, yaw_deg=40)
    local = local_positions(m.canonical_positions(POSE_JOINTS), POSE_JOINTS)
    twice = mirror(mirror(local, POSE_JOINTS), POSE_JOINTS)
    assert np.allclose(twice, local)
    j = list(POSE_JOINTS)
    mir = mirror(local, POSE_JOINTS)
    assert np.allclose(mir[:, j.index("lwrist"), 0], -local[:, j.index("rwrist"), 0])


def test_retarget_matches_chain_loop_and_round_trips(store):
    """The vectorised retargeting against a joint-by-joint walk up the chain; with a
    performer's own lengths it gives back the performer's poses."""
    rng = np.random.default_rng(3)
    lengths = rng.uniform(0.05, 0.5, len(POSE_JOINTS))
    lengths[0] = 0.0
    rows = np.array([0, 7, 95, 300])
    fast = store.retarget(lengths, rows)
    parents = bone_parents(POSE_JOINTS)
    for n, r in enumerate(rows):
        for j in range(len(POSE_JOINTS)):
            want, b = np.zeros(3), j
            while b > 0:
                want += lengths[b] * store.dirs[r, b]
                b = parents[b]
            assert np.allclose(fast[n, j], want, atol=1e-5)
    m = periodic_motion(30, 0.0, scale=1.15)
    local = local_positions(m.canonical_positions(POSE_JOINTS), POSE_JOINTS)
    own = bone_lengths(m.canonical_positions(POSE_JOINTS), POSE_JOINTS)
    assert np.abs(store.retarget(own, np.arange(30)) - local).max() < 1e-5
    d, length = directions(local, parents)
    assert np.allclose(length[:, 1:], own[1:], atol=1e-6)


def test_save_load_memory_maps(store, tmp_path):
    store.save(tmp_path / "prior")
    store.save(tmp_path / "prior")  # overwrites atomically
    back = PriorStore.load(tmp_path / "prior")
    assert isinstance(back.dirs, np.memmap) and np.array_equal(back.dirs, store.dirs)
    assert back.clips == store.clips and back.joints == store.joints and back.fps == store.fps
    with pytest.raises(DataError, match="clips.json"):
        PriorStore.load(tmp_path)


def test_reconstruction_of_another_performer_is_accurate(store):
    # test poses lie half a frame between prior poses, on a 15 % smaller skeleton, under another heading
    test = periodic_motion(60, 0.5 / 30, yaw_deg=-120, name="t")
    cache = PriorCache(store)
    prior = cache.for_motion(test, "none")
    assert cache.for_motion(test, "none") is prior
    rec, e = reconstruct_motion(test, prior, ReconstructParams(k=16))
    assert e["avg_cm"] < 1.0 and e["max_frame_cm"] < 3.0 and e["max_joint_cm"] < 6.0
    assert rec.n_frames == 60 and rec.skeleton is test.skeleton and e["fk_avg_cm"] < e["avg_cm"] + 0.5
    # without retargeting (the prior on the prior performer's skeleton) it does far worse
    big = PosePrior.build(
        store, bone_lengths(periodic_motion(2, scale=1.15).canonical_positions(POSE_JOINTS), POSE_JOINTS)
    )
    _, e_big = reconstruct_motion(test, big, ReconstructParams(k=16))
    assert e_big["avg_cm"] > 2 * e["avg_cm"]
    world, heading = reconstruct_positions(synthetic_markers(test), prior, ReconstructParams(k=16))
    assert np.abs(np.angle(np.exp(1j * (heading - np.deg2rad(-120))))).max() < np.deg2rad(15)
    # every bone has the performer's length
    got = bone_lengths(world, POSE_JOINTS)
    assert np.allclose(got, prior.lengths, atol=1e-6)


def test_leave_out_and_unseen_amplitude(store):
    test = periodic_motion(45, 0.2, amp=1.0, yaw_deg=30, name="a", subject="s1")
    assert withheld(store, test, "clip").tolist() == [True, True, False, False, False, False]
    assert withheld(store, test, "subject").tolist() == [True, True, True, True, False, False]
    assert not withheld(store, test, "none").any()
    prior = PriorCache(store).for_motion(test, "clip")
    assert len(prior.poses) == 240
    _, e = reconstruct_motion(test, prior, ReconstructParams(k=24))
    assert e["avg_cm"] < 3.0  # interpolating between amplitudes 0.9 and 1.1


def test_input_validation(store):
    prior = PriorCache(store).for_motion(periodic_motion(2), "none")
    with pytest.raises(DataError):
        reconstruct_positions(np.zeros((5, 4, 3)), prior)
    with pytest.raises(DataError):
        reconstruct_positions(np.zeros((5, 2, 3)), prior, model=ReconstructModel(markers=("head", "lwrist")))
    nan = np.zeros((5, 6, 3))
    nan[2, 1] = np.nan
    with pytest.raises(DataError, match="NaN"):
        reconstruct_positions(nan, prior)
    assert reconstruct_positions(np.zeros((0, 6, 3)), prior)[0].shape == (0, len(prior.joints), 3)
    m = periodic_motion(3, 0.5 / 30)
    for n in (1, 2, 3):  # one-frame clips and clips shorter than the backward pass
        world, _ = reconstruct_positions(synthetic_markers(m.slice(0, n)), prior, ReconstructParams(k=16))
        assert world.shape == (n, len(prior.joints), 3)
        assert joint_errors(world, m.slice(0, n).canonical_positions(prior.joints))[2] < 3.0
    with pytest.raises(DataError, match="frames left"):
        PosePrior.build(store, prior.lengths, np.zeros(len(store.clips), bool))
    with pytest.raises(DataError, match="bone lengths"):
        PosePrior.build(store, prior.lengths[:3])


def test_test_rate_differs_from_prior_rate(store):
    """A 60 Hz take against the 30 Hz prior."""
    from mocapflow.framework.normalize import resample

    test = resample(periodic_motion(60, 0.5 / 30, yaw_deg=50, name="t"), 60.0)
    prior = PriorCache(store).for_motion(test, "none")
    _, e = reconstruct_motion(test, prior, ReconstructParams(k=16))
    assert e["avg_cm"] < 1.5


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
    assert all(0 < c["avg_cm"] < 10 and c["max_joint_cm"] >= c["max_cm"] >= c["avg_cm"] for c in clips)
    assert all(c["prior_frames"] < 2 * 656 for c in clips)  # the other takes, each with its mirror image
    db = rec.motions()
    assert sorted(m.name for m in db.motions) == ["02_01_recon", "16_15_recon"]
    assert sum(m.n_frames for m in db.motions) == sum(c["n_frames"] for c in clips)
    conf = rec.table("confidence").to_pylist()
    assert len(conf) == sum(c["n_frames"] for c in clips) and all(0 < r["confidence"] <= 1 for r in conf)
    assert all(0 < c["confidence_min"] <= c["confidence_mean"] <= 1 for c in clips)
    assert len(list((tmp_path / "bvh").glob("*.bvh"))) == 2
    t3 = Dataset(tmp_path / "evaluation").table("table3").to_pylist()
    assert {r["prior"] for r in t3} == {"CMU-", "CMU"}
    # the test subject's other takes help: leaving the subject out costs accuracy on average
    by = {p: np.mean([r["avg_cm"] for r in t3 if r["prior"] == p]) for p in ("CMU-", "CMU")}
    assert by["CMU"] <= by["CMU-"]


def _map_pose_numpy(
    nb: np.ndarray,
    sel: np.ndarray,
    rel: np.ndarray,
    theta: float,
    pred: np.ndarray,
    has_pred: bool,
    w_m: float,
    w_s: float,
    alternations: int,
) -> tuple[np.ndarray, float]:
    """The MAP pose (D,) and heading of one search (the slow twin of
    ``_reconstruct_kernels.map_pose``): local model of neighbours ``nb`` (K, D), marker
    term on columns ``sel`` for markers ``rel`` (M, 3) relative to the root, smoothness
    towards ``pred`` (if ``has_pred``), alternated with the heading."""
    mu, x, gram = _local_model(nb)
    xs = x[:, sel]
    lhs = w_m * xs @ xs.T + max(len(nb) - 1, 1) * np.eye(len(nb))
    if has_pred:
        lhs += w_s * gram
    guess = mu
    for _ in range(alternations):
        obs = rotate_about_y(rel[None], np.array([-theta]))[0].ravel()
        rhs = w_m * xs @ (obs - mu[sel])
        if has_pred:
            rhs += w_s * x @ (pred - mu)
        guess = mu + x.T @ np.linalg.solve(lhs, rhs)
        theta = _yaw_align(guess[sel].reshape(-1, 3), rel)
    return guess, theta


def test_map_pose_kernel_matches_numpy_twin():
    from mocapflow.plugins.similarity.applications._reconstruct_kernels import map_pose

    rng = np.random.default_rng(5)
    nb = rng.normal(size=(20, 75))
    sel = np.arange(18) * 3 % 75
    rel = rng.normal(size=(6, 3))
    pred = rng.normal(size=75)
    for has_pred in (True, False):
        a, ta = map_pose(nb, sel, rel, 0.3, pred, has_pred, 4e4, 2.5e3, 2)
        b, tb = _map_pose_numpy(nb, sel, rel, 0.3, pred, has_pred, 4e4, 2.5e3, 2)
        assert np.allclose(a, b, atol=1e-9) and ta == pytest.approx(tb)


def vicon_markers(m: Motion):
    """Plug-in-Gait style markers around the joints of ``m`` whose means are the control points."""
    from mocapflow.framework.markers import Markers

    j = {n: m.canonical_positions((n,))[:, 0] for n in ("lhip", "rhip", "head", "lwrist", "rwrist", "lankle", "rankle")}
    up, fw, side = np.array([0, 0.05, 0]), np.array([0, 0, 0.05]), np.array([0.05, 0, 0])
    lab = {
        "LFWT": j["lhip"] + up + fw,
        "LBWT": j["lhip"] + up - fw,
        "RFWT": j["rhip"] + up + fw,
        "RBWT": j["rhip"] + up - fw,
        "LFHD": j["head"] + side + fw,
        "RFHD": j["head"] - side + fw,
        "LBHD": j["head"] + side - fw,
        "RBHD": j["head"] - side - fw,
        "LWRA": j["lwrist"] + fw / 2,
        "LWRB": j["lwrist"] - fw / 2,
        "RWRA": j["rwrist"] + fw / 2,
        "RWRB": j["rwrist"] - fw / 2,
        "LANK": j["lankle"],
        "RANK": j["rankle"],
        "CLAV": j["head"] - 3 * up,
    }
    return Markers(
        tuple(f"subj:{k}" for k in lab), np.stack(list(lab.values()), 1), m.fps, name="take", metadata={"up_axis": "+y"}
    )


def test_marker_set_control_points_and_errors():
    from mocapflow.framework.markers import Markers
    from mocapflow.plugins.similarity.applications.reconstruct_markers import control_from_markers, control_from_motion

    m = periodic_motion(20, yaw_deg=25)
    mk = vicon_markers(m)
    control, heading, name, mapping = control_from_markers(mk)
    want, want_heading = control_from_motion(m)
    assert name == "vicon" and mapping["lwrist"] == ("subj:LWRA", "subj:LWRB")
    assert np.abs(control[:, 1:] - want[:, 1:]).max() < 1e-9 and np.allclose(heading, want_heading)
    assert np.abs(control[:, 0] - want[:, 0]).max() < 0.01  # the pelvis markers' mean: near the root
    gappy = mk.positions.copy()
    gappy[3:6, 12] = np.nan  # LANK missing for 3 frames: interpolated
    c2, _, _, _ = control_from_markers(Markers(mk.labels, gappy, mk.fps, metadata=mk.metadata))
    assert np.abs(c2 - control).max() < 0.05 and np.array_equal(c2[:3], control[:3])
    with pytest.raises(DataError, match="no marker set fits"):
        control_from_markers(mk.select([lb for lb in mk.labels if "RANK" not in lb]))
    with pytest.raises(DataError, match="unknown marker set"):
        control_from_markers(mk, "nope")


def test_cli_and_pipeline_from_a_marker_take(tmp_path, store):
    """``mocapflow reconstruct take.trc`` and the ``reconstruct_markers`` step give the same
    take, on the performer's skeleton, close to the motion the markers came from."""
    from mocapflow.framework import Dataset, get_plugin_manager, load_registries
    from mocapflow.framework.cli import main
    from mocapflow.framework.runner import run_pipeline
    from mocapflow.plugins.formats.trc import write_trc

    truth = periodic_motion(45, 0.5 / 30, yaw_deg=-60, name="take")
    write_trc(vicon_markers(truth), tmp_path / "take.trc")
    bvh = load_registries(kinds=["formats"], entry_points=False).motion_format(tmp_path / "x.bvh", writing=True)
    bvh.write(truth, tmp_path / "performer.bvh")
    store.save(tmp_path / "prior")
    out = tmp_path / "out.bvh"
    argv = ["reconstruct", str(tmp_path / "take.trc"), "--prior", str(tmp_path / "prior"), "-o", str(out), "-k", "16"]
    # markers on the joints themselves: nothing to calibrate (reconstruct_calibrate tests that)
    conf = tmp_path / "conf.csv"
    skel = ["--skeleton", str(tmp_path / "performer.bvh"), "--calibration", "off"]
    assert main([*argv, *skel, "--confidence", str(conf)]) == 0
    rows = conf.read_text().splitlines()
    assert rows[0] == "frame,time_s,confidence,novelty,misfit_cm,reach_cm,limit" and len(rows) == 46
    values = np.array([[float(v) for v in r.split(",")] for r in rows[1:]])
    assert np.all((values[:, 2] >= 0) & (values[:, 2] <= 1)) and values[1, 1] == pytest.approx(1 / truth.fps, abs=1e-6)
    assert main([*argv, *skel, "--confidence", str(tmp_path / "conf.txt")]) == 2  # named .csv, refused before work
    assert not (tmp_path / "conf.txt").exists()
    rec = bvh.read(out)
    err = joint_errors(rec.canonical_positions(POSE_JOINTS), truth.canonical_positions(POSE_JOINTS))[2]
    assert rec.n_frames == 45 and err < 2.0
    assert main(argv) == 2  # a marker take needs the performer's skeleton
    yaml = tmp_path / "p.yaml"
    yaml.write_text(
        f"""name: t
workspace: {tmp_path / "ws"}
steps:
  markers:
    uses: formats.load_markers
    with: {{paths: ["{tmp_path / "take.trc"}"]}}
  recon:
    uses: analyses.reconstruct_markers
    inputs: {{prior: prior, markers: markers}}
    with: {{skeleton: "{tmp_path / "performer.bvh"}", k: 16}}
  prior:
    uses: formats.load
    with: {{paths: ["{tmp_path / "performer.bvh"}"]}}
"""
    )
    run_pipeline(yaml, workspace=tmp_path / "ws", jobs=1, pm=get_plugin_manager(entry_points=False))
    fit = Dataset(tmp_path / "ws" / "recon").table("fit").to_pylist()
    assert fit[0]["marker_set"] == "vicon" and fit[0]["n_frames"] == 45 and fit[0]["fit_mean_cm"] < 1.0
    assert 0 <= fit[0]["confidence_min"] <= fit[0]["confidence_mean"] <= 1
    conf_rows = Dataset(tmp_path / "ws" / "recon").table("confidence")
    assert conf_rows.num_rows == 45 and conf_rows.column("frame").to_pylist() == list(range(45))
    offsets = Dataset(tmp_path / "ws" / "recon").table("offsets").to_pylist()
    assert [r["point"] for r in offsets] == ["root", "head", "lwrist", "rwrist", "lankle", "rankle"]
    assert not any(r["calibrated"] for r in offsets)  # no elbow/knee markers: nothing to calibrate


def test_output_skeleton_from_an_asf_or_a_take_through_the_format_registry():
    from pathlib import Path

    from mocapflow.framework import load_registries
    from mocapflow.plugins.similarity.applications.reconstruct_markers import read_skeleton

    cmu = Path(__file__).resolve().parents[3] / "examples" / "data" / "cmu" / "16"
    reg = load_registries(kinds=["formats"], entry_points=False)
    from_asf = read_skeleton(cmu / "16.asf", reg)
    from_take = read_skeleton(cmu / "16_01.amc", reg)
    assert isinstance(from_asf, Skeleton) and from_asf.names == from_take.names
    np.testing.assert_allclose(from_asf.offsets, from_take.offsets)
