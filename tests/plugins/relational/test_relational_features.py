"""Relational features (Müller et al. 2005, Table 1): primitives, kernels, constructed poses, real clips."""

from __future__ import annotations

import glob

import numpy as np
import pytest
from conftest import corpus_path
from naive import relational as naive
from naive.relational import motion_from_positions, pose_array

from mocapflow.framework.database import MotionDatabase
from mocapflow.framework.errors import ConfigError
from mocapflow.plugins.relational import primitives as prim
from mocapflow.plugins.relational.body import body_measures
from mocapflow.plugins.relational.feature_table import feature_column
from mocapflow.plugins.relational.features import (
    FEATURE_IDS,
    FEATURES,
    THRESHOLDS,
    RelationalFeatures,
    feature_values,
    relational_features,
    set_codes,
)

RNG = np.random.default_rng(7)


def bits_of(*frames, fps=30.0, **params):
    m = motion_from_positions(np.stack(frames), fps=fps)
    return RelationalFeatures(**params).transform_bits(m)


def on(bits_row):
    return {FEATURE_IDS[i] for i in np.flatnonzero(bits_row)}


# --- primitives against their naive twins -------------------------------------------------
def test_primitives_match_naive():
    p = [RNG.normal(size=(50, 3)) for _ in range(4)]
    np.testing.assert_allclose(prim.plane_distance(*p, offset=0.1), naive.plane_distance(*p, 0.1), atol=1e-4)
    np.testing.assert_allclose(prim.normal_plane_distance(*p), naive.normal_plane_distance(*p), atol=1e-4)
    np.testing.assert_allclose(prim.point_segment_distance(*p[:3]), naive.point_segment_distance(*p[:3]), atol=1e-4)
    np.testing.assert_allclose(prim.segment_segment_distance(*p), naive.segment_segment_distance(*p), atol=2e-3)
    np.testing.assert_allclose(prim.angle_between(*p), naive.angle_between(*p), atol=0.05)


def test_segment_distance_awkward_cases():
    z = np.zeros(3)
    # parallel segments, a point segment, crossing segments
    assert prim.segment_segment_distance(z, [1, 0, 0], [0, 1, 0], [1, 1, 0]) == pytest.approx(1, abs=1e-6)
    assert prim.segment_segment_distance(z, z, [0, 2, 0], [0, 3, 0]) == pytest.approx(2, abs=1e-6)
    assert prim.segment_segment_distance([-1, 0, 0], [1, 0, 0], [0, -1, 0.5], [0, 1, 0.5]) == pytest.approx(
        0.5, abs=1e-6
    )
    # a fixed normal direction broadcasts against per-frame points
    q = np.array([[0, 2, 0], [0, -1, 0]], float)
    np.testing.assert_allclose(prim.normal_plane_distance(z, [0, 1, 0], z, q), [2, -1], atol=1e-6)


def test_speed_never_crosses_clip_boundaries():
    p = np.cumsum(RNG.normal(size=(12, 3)), axis=0)
    offsets = np.array([0, 1, 5, 5, 12])  # a one-frame clip and an empty clip
    got = prim.speed(p, 30.0, offsets)
    np.testing.assert_allclose(got, naive.speed(p, 30.0, offsets), rtol=1e-5)
    assert got[0] == 0.0
    # constant signal: zero speed everywhere
    assert not prim.speed(np.ones((5, 3)), 30.0).any()


def test_kernel_matches_naive_features():
    # random perturbations of the standing pose, two clips, a missing joint (fallback)
    frames = pose_array()[None] + RNG.normal(scale=0.15, size=(40, 25, 3))
    frames[:, naive.CANONICAL_JOINTS.index("ltoes")] = np.nan  # missing joint -> fallback lankle
    offsets = np.array([0, 1, 40])
    meas = {"humerus_length": 0.28, "shoulder_width": 0.4, "hip_width": 0.2}
    for over in ({}, {"foot_raised": 0.5, "bent_angle": 100.0}):
        params = RelationalFeatures.Params(thresholds=over)
        got = relational_features(frames, 30.0, meas, params, offsets)
        want = naive.feature_bits(FEATURES, params, frames, 30.0, meas, offsets)
        # values at a threshold may round either way in float32: allow a tiny fraction
        assert (got != want).mean() < 0.005
    vals = feature_values(frames, 30.0, prim.clip_starts(offsets, 40))
    ref = naive.feature_values(FEATURES, frames, 30.0, offsets)
    deg = np.array([d.unit == "deg" for d in FEATURES])
    np.testing.assert_allclose(vals[:, ~deg], ref[:, ~deg], atol=2e-3)
    np.testing.assert_allclose(np.degrees(np.arccos(vals[:, deg])), ref[:, deg], atol=0.1)


# --- every feature on constructed poses -----------------------------------------------------
STAND = pose_array()
MOVED = {
    "L1": None,  # on while standing (the paper's F^r)
    "L3": dict(rtoes=(-0.1, 0.5, 0.2), rankle=(-0.1, 0.55, 0.1)),
    "L4": dict(ltoes=(0.1, 0.5, 0.2), lankle=(0.1, 0.55, 0.1)),
    "L7": dict(rankle=(-0.1, 0.5, -0.45), rtoes=(-0.1, 0.45, -0.5)),
    "L8": dict(lankle=(0.1, 0.5, -0.45), ltoes=(0.1, 0.45, -0.5)),
    "L9": dict(rankle=(-0.5, 0.15, 0), rtoes=(-0.5, 0.1, 0.12)),
    "L10": dict(lankle=(0.5, 0.15, 0), ltoes=(0.5, 0.1, 0.12)),
    "L11": dict(rankle=(0.2, 0.08, 0.05), rtoes=(0.2, 0.0, 0.15)),
    "U1": dict(relbow=(-0.2, 1.45, 0.28), rwrist=(-0.2, 1.45, 0.55), rfingers=(-0.2, 1.45, 0.65)),
    "U2": dict(lelbow=(0.2, 1.45, 0.28), lwrist=(0.2, 1.45, 0.55), lfingers=(0.2, 1.45, 0.65)),
    "U3": dict(relbow=(-0.2, 1.73, 0), rwrist=(-0.2, 1.98, 0), rfingers=(-0.2, 2.08, 0)),
    "U4": dict(lelbow=(0.2, 1.73, 0), lwrist=(0.2, 1.98, 0), lfingers=(0.2, 2.08, 0)),
    "U5": dict(relbow=(-0.48, 1.45, 0), rwrist=(-0.75, 1.45, 0), rfingers=(-0.85, 1.45, 0)),
    "U6": dict(lelbow=(0.48, 1.45, 0), lwrist=(0.75, 1.45, 0), lfingers=(0.85, 1.45, 0)),
    "U7": dict(rwrist=(-0.25, 1.17, 0.25), rfingers=(-0.25, 1.17, 0.35)),
    "U8": dict(lwrist=(0.25, 1.17, 0.25), lfingers=(0.25, 1.17, 0.35)),
    "U11": dict(
        rwrist=(0.15, 1.2, 0.2), lwrist=(-0.15, 1.2, 0.25), rfingers=(0.2, 1.2, 0.3), lfingers=(-0.2, 1.2, 0.3)
    ),
    "U12": dict(
        rwrist=(-0.04, 1.2, 0.3), rfingers=(0.0, 1.2, 0.38), lwrist=(0.04, 1.2, 0.3), lfingers=(0.0, 1.22, 0.38)
    ),
    "M1": dict(rwrist=(-0.15, 0.7, 0.05), rfingers=(-0.15, 0.6, 0.05)),
    "M2": dict(lwrist=(0.15, 0.7, 0.05), lfingers=(0.15, 0.6, 0.05)),
    "M3": dict(relbow=(-0.3, 1.5, 0.2), rwrist=(-0.1, 1.65, 0.05), rfingers=(-0.05, 1.7, 0.05)),
    "M4": dict(lelbow=(0.3, 1.5, 0.2), lwrist=(0.1, 1.65, 0.05), lfingers=(0.05, 1.7, 0.05)),
    "M5": dict(rwrist=(-0.05, 0.95, 0.1), rfingers=(0.0, 0.9, 0.12)),
    "M6": dict(lwrist=(0.05, 0.95, 0.1), lfingers=(0.0, 0.9, 0.12)),
    "M7": dict(
        lowerback=(0, 1.02, 0.12),
        upperback=(0, 1.04, 0.25),
        chest=(0, 1.05, 0.35),
        neck=(0, 1.05, 0.5),
        head=(0, 1.05, 0.6),
        headtop=(0, 1.05, 0.75),
    ),
}


@pytest.mark.parametrize("fid", sorted(MOVED, key=lambda f: (f[0], int(f[1:]))))
def test_static_feature_on_constructed_pose(fid):
    standing = on(bits_of(STAND)[0])
    assert standing == {"L1", "L2"}
    if MOVED[fid] is None:
        assert fid in standing
        return
    got = on(bits_of(pose_array(**MOVED[fid]))[0])
    assert fid in got, f"{fid} ({FEATURES[feature_column(fid)].description}) should fire: {sorted(got)}"
    # the mirrored feature stays off
    mirror = {
        "L3": "L4",
        "L4": "L3",
        "L7": "L8",
        "L8": "L7",
        "L9": "L10",
        "L10": "L9",
        "U1": "U2",
        "U2": "U1",
        "U3": "U4",
        "U4": "U3",
        "U5": "U6",
        "U6": "U5",
        "U7": "U8",
        "U8": "U7",
        "M1": "M2",
        "M2": "M1",
        "M3": "M4",
        "M4": "M3",
        "M5": "M6",
        "M6": "M5",
    }.get(fid)
    if mirror:
        assert mirror not in got


def test_foot_front_turns_off_when_foot_behind():
    got = on(bits_of(pose_array(rtoes=(-0.1, 0.0, -0.3), rankle=(-0.1, 0.08, -0.4)))[0])
    assert "L1" not in got and "L2" in got
    got = on(bits_of(pose_array(ltoes=(0.1, 0.0, -0.3), lankle=(0.1, 0.08, -0.4)))[0])
    assert "L2" not in got and "L1" in got


@pytest.mark.parametrize(
    "fid,joints", [("L5", ["rtoes"]), ("L6", ["ltoes"]), ("U9", ["rwrist"]), ("U10", ["lwrist"]), ("M8", None)]
)
def test_speed_features(fid, joints):
    frames = np.stack([STAND] * 5)
    step = np.array([0.0, 0.0, 0.1])  # 0.1 m per frame at 30 Hz = 3 m/s > 2 humerus lengths/s
    cols = slice(None) if joints is None else [naive.CANONICAL_JOINTS.index(j) for j in joints]
    frames[:, cols] += np.arange(5)[:, None, None] * step
    bits = bits_of(*frames)
    assert bits[:, feature_column(fid)].all()
    assert not bits_of(*[STAND] * 5)[:, feature_column(fid)].any()
    if fid != "M8":  # the whole body translating: the hand is not fast relative to the root
        assert not bits[:, feature_column("M8")].any()
    else:
        assert not bits[:, feature_column("U9")].any()


def test_thresholds_scale_with_body_size():
    # the same pose scaled by 1.5 (a bigger skeleton) gives the same features
    for fid, change in MOVED.items():
        if change is None:
            continue
        p = pose_array(**change)
        m = motion_from_positions(np.stack([p * 1.5]))
        big = naive.star_skeleton(pose_array() * 1.5)
        m = m.with_arrays(skeleton=big)
        np.testing.assert_array_equal(RelationalFeatures().transform_bits(m)[0], bits_of(p)[0], err_msg=fid)


def test_database_transform_equals_per_clip_and_codes():
    a = motion_from_positions(pose_array()[None] + RNG.normal(scale=0.1, size=(9, 25, 3)))
    b = motion_from_positions(pose_array()[None] + RNG.normal(scale=0.1, size=(1, 25, 3)))
    fe = RelationalFeatures()
    whole = fe.transform(MotionDatabase([a, b]))
    np.testing.assert_array_equal(whole, np.concatenate([fe.transform(a), fe.transform(b)]))
    assert whole.dtype == np.float32 and whole.shape == (10, 31)
    lower = set_codes(whole, "lower")
    np.testing.assert_array_equal(lower, (whole[:, :11] > 0.5) @ (1 << np.arange(11)))


def test_feature_lookup():
    assert feature_column("l3") == feature_column("rfoot_raised") == 2
    assert feature_column("M8") == 30
    with pytest.raises(ConfigError):
        feature_column("rfoot_rased")


# --- real clips: features fire where they should ------------------------------------------
def _clip(pattern: str):
    from mocapflow.framework.normalize import resample
    from mocapflow.plugins.formats.asf_amc import read_amc

    root = corpus_path("hdm05", "amc")
    files = sorted(glob.glob(str(root / "*" / pattern)))
    return resample(read_amc(files[0]), 30.0)


def test_real_clips_fire_where_they_should():
    fe = RelationalFeatures()
    kick = fe.transform_bits(_clip("*kickLFront*"))  # HDM05 kicks are left-foot front kicks
    col = feature_column
    assert kick[:, col("lfoot_raised")].mean() > 0.1
    assert kick[:, col("rfoot_raised")].mean() < kick[:, col("lfoot_raised")].mean()
    squat = fe.transform_bits(_clip("*squat*"))
    assert (squat[:, col("rknee_bent")] & squat[:, col("lknee_bent")]).mean() > 0.3
    assert not squat[:, col("rfoot_raised")].any()
    grab = fe.transform_bits(_clip("*grabHighR*"))
    assert grab[:, col("rhand_raised")].mean() > 0.2 and grab[:, col("lhand_raised")].mean() < 0.05
    jog = fe.transform_bits(_clip("*jogLeftCircle*"))
    assert jog[:, col("root_fast")].mean() > 0.5 and jog[:, col("rfoot_fast")].mean() > 0.3
    lie = fe.transform_bits(_clip("*lieDownFloor*"))
    assert lie[:, col("torso_bent")].any()
    # a whole clip is as fast to compute as a database of it, and measures come from its skeleton
    assert body_measures(_clip("*squat*").skeleton)["humerus_length"] > 0.2


def test_docs_table_lists_every_feature_with_its_thresholds():
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[3] / "docs" / "relational-features.md").read_text()
    for d in FEATURES:
        row = next((line for line in doc.splitlines() if line.startswith(f"| {d.id} |")), None)
        assert row is not None, f"{d.id} missing from docs/relational-features.md"
        assert f"`{d.name}`" in row and d.definition in row and f"{THRESHOLDS[d.param]:g}" in row, row
