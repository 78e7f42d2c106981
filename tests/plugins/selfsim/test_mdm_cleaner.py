"""The MDM cleaner end to end on synthetic motions: the paper's analysis, detection, repair, contexts."""

from __future__ import annotations

import numpy as np
import pytest
from naive.cleaning import synthetic_walk

from mocapflow.framework import quaternions as quat
from mocapflow.framework.database import MotionDatabase
from mocapflow.framework.errors import DataError
from mocapflow.framework.normalize import resample
from mocapflow.plugins.selfsim.cleaner import MDMCleaner, MDMParams
from mocapflow.plugins.selfsim.paper.mdm import context_motions, digression_map, knn_spread
from mocapflow.plugins.selfsim.paper.repair import Contact, repair_motion, repair_texture, sparse_reconstruction


def _with_offset(motion, joint="lelbow", start=200, stop=206, angle=1.2):
    rot = motion.rotations.copy()
    j = motion.skeleton.canonical[joint]
    rot[start:stop, j] = quat.mul(rot[start:stop, j], quat.from_axis_angle(np.array([0, 0, 1.0]), np.array(angle)))
    return motion.with_arrays(rotations=rot), j


@pytest.fixture(scope="module")
def corrupted():
    clean = synthetic_walk(360, seed=3)
    bad, j = _with_offset(clean)
    res = digression_map(bad, None, MDMParams())
    return clean, bad, j, res


def test_mdm_is_a_map_in_unit_range_and_finds_the_error(corrupted):
    clean, bad, j, res = corrupted
    assert res.mdm.shape == (360, 24) and np.all((res.mdm >= 0) & (res.mdm <= 1))
    c = res.joints.index("lelbow")
    assert np.all(res.mdm[200:206, c] > 0.9)
    # the error stands out of its joint's row; the paper's row mean still flags much clean motion
    assert res.difference[200:206, c].min() > 10 * np.median(res.difference[:, c])


def test_rows_are_divided_by_their_mean(corrupted):
    _, _, _, res = corrupted
    m = res.difference / np.maximum(res.difference.mean(axis=0, keepdims=True), 0.01)
    np.testing.assert_allclose(res.mdm, 1 - np.exp(-(m**2)))


def test_knn_spread_is_the_rms_half_angle_about_the_chordal_mean():
    rng = np.random.default_rng(0)
    base = quat.from_axis_angle(np.array([0.3, 0.9, 0.1]) / np.linalg.norm([0.3, 0.9, 0.1]), np.array(0.7))
    outer = np.zeros((3, 2, 4, 4))
    count = np.zeros((3, 2), np.int64)
    want = np.zeros((3, 2))
    for t in range(3):
        for j in range(2):
            if (t, j) == (2, 1):
                continue  # an uncovered cell
            n = 1 + 4 * t + j
            axis = rng.standard_normal((n, 3))
            axis /= np.linalg.norm(axis, axis=1, keepdims=True)
            q = quat.mul(
                np.broadcast_to(base, (n, 4)), quat.from_axis_angle(axis, (0.1 + 0.3 * j) * rng.standard_normal(n))
            )
            q = q * rng.choice([-1.0, 1.0], size=(n, 1))  # sign flips must not matter
            outer[t, j] = np.einsum("ni,nj->ij", q, q)
            count[t, j] = n
            # slow and obvious: the chordal mean by power iteration, then the angles to it
            m = q[0].copy()
            for _ in range(500):
                m = outer[t, j] @ m
                m /= np.linalg.norm(m)
            half = quat.geodesic_angle(q, np.broadcast_to(m, q.shape)) / 2
            want[t, j] = 2 * np.arcsin(np.sqrt(np.mean(np.sin(half) ** 2)))
    got = knn_spread(outer, count)
    np.testing.assert_allclose(got, want, atol=1e-7)
    assert got[2, 1] == 0.0 and got[0, 0] == pytest.approx(0.0, abs=1e-7)  # one sample: no scatter


def test_repair_changes_only_flagged_cells_and_undoes_the_error(corrupted):
    clean, bad, j, res = corrupted
    p = MDMParams(mode="paper")
    new, flagged = repair_texture(res, p.threshold, p.savgol_window, p.savgol_order)
    unchanged = ~flagged
    assert np.array_equal(new[unchanged], res.texture.q[unchanged])
    cleaned, edits = repair_motion(bad, res, p)
    err_before = quat.geodesic_angle(bad.rotations[200:206, j], clean.rotations[200:206, j])
    err_after = quat.geodesic_angle(cleaned.rotations[200:206, j], clean.rotations[200:206, j])
    assert err_after.max() < 0.2 * err_before.min()
    changed = np.zeros_like(bad.rotations[..., 0], bool)
    changed[edits["frame"].to_numpy(), edits["joint"].to_numpy()] = True
    same = ~changed
    assert np.array_equal(cleaned.rotations[same], bad.rotations[same])
    assert set(edits.column_names) >= {"clip_id", "frame", "joint", "joint_name", "old_rotation", "new_rotation"}


def test_detect_and_repair_work_at_the_input_rate():
    clean = synthetic_walk(600, fps=60.0, seed=5)
    bad, j = _with_offset(clean, start=300, stop=312)
    cleaner = MDMCleaner(mode="paper")
    mdm = cleaner.detect(bad)
    assert mdm.shape == (600, bad.n_joints)
    assert mdm[300:312, j].min() > 0.5
    cleaned, edits = cleaner.repair(bad)
    assert cleaned.fps == 60.0 and cleaned.n_frames == 600
    f = edits["frame"].to_numpy()[edits["joint"].to_numpy() == j]
    assert set(range(300, 312)) <= set(f.tolist())
    assert len(f) < 0.2 * 600  # a local repair, not a smoothing of the whole track
    err = quat.geodesic_angle(cleaned.rotations[302:310, j], clean.rotations[302:310, j])
    assert err.max() < 0.3


def test_contexts():
    take = synthetic_walk(240, seed=1, name="take")
    others = [synthetic_walk(240, seed=s, name=f"o{s}") for s in (2, 3)]
    assert [c.name for c in context_motions(take, MotionDatabase([take, *others]))] == ["take", "o2", "o3"]
    assert [c.name for c in context_motions(take, others[0])] == ["take", "o2"]
    with pytest.raises(DataError):
        context_motions(take, None, include_self=False)
    with pytest.raises(DataError):
        context_motions(take, "nonsense")
    bad, _ = _with_offset(take, start=100, stop=106)
    one = digression_map(bad, others, MDMParams())
    c = one.joints.index("lelbow")
    assert one.mdm[100:106, c].min() > 0.5


def test_short_clip_has_an_all_zero_map():
    res = digression_map(synthetic_walk(10), None, MDMParams())
    assert res.mdm.shape == (10, 24) and not res.mdm.any()


def test_contact_constraint_picks_the_word_closest_to_the_contact(corrupted):
    clean, bad, j, res = corrupted
    p = MDMParams()
    m24 = res.texture.motion
    e = m24.skeleton.canonical["lfingers"]
    target = clean.positions[203, e] - clean.root_translation[203] + m24.root_translation[203]
    new_c, _ = repair_texture(
        res, p.threshold, p.savgol_window, p.savgol_order, contacts=[Contact("lfingers", 203, tuple(target))]
    )
    assert new_c.shape == res.texture.q.shape


def test_sparse_reconstruction_from_nine_joints():
    context = [synthetic_walk(360, seed=s) for s in (11, 12)]
    truth = synthetic_walk(240, seed=13)
    known = ("neck", "lshoulder", "rshoulder", "lelbow", "relbow", "lhip", "rhip", "lknee", "rknee")
    rot = truth.rotations.copy()
    unknown = [truth.skeleton.canonical[j] for j in ("lankle", "rankle", "lowerback", "chest")]
    rot[:, unknown] = quat.identity((len(rot), len(unknown)))
    sparse = truth.with_arrays(rotations=rot)
    out = sparse_reconstruction(sparse, context, known, MDMParams())
    ref = resample(truth, 24.0)
    err_out = quat.geodesic_angle(out.rotations[:, unknown], ref.rotations[:, unknown]).mean()
    err_in = quat.geodesic_angle(resample(sparse, 24.0).rotations[:, unknown], ref.rotations[:, unknown]).mean()
    assert err_out < 0.5 * err_in


def test_heatmap_png(tmp_path, corrupted):
    pytest.importorskip("matplotlib")
    from mocapflow.plugins.selfsim.plots import mdm_heatmap

    _, _, _, res = corrupted
    path = mdm_heatmap(res.mdm, res.joints, tmp_path / "m.png", title="test")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_params_reject_unknown_keys_and_keep_paper_defaults():
    from pydantic import ValidationError

    p = MDMParams()
    assert (p.fps, p.source_length, p.source_step, p.target_length, p.k, p.threshold) == (24.0, 15, 5, 20, 5, 0.5)
    assert [g.drop for g in p.groups] == [3, 1, 1, 1, 1] and len(p.joints) == 24
    assert p.mode == "calibrated" and p.calibrated.false_alarm_rate == 2e-3
    assert MDMParams(calibrated={"false_alarm_rate": 1e-3}).calibrated.false_alarm_rate == 1e-3
    with pytest.warns(DeprecationWarning, match="false_alarm_rate"):
        MDMParams(calibrated={"false_alarm": 0.002})
    with pytest.raises(ValidationError):
        MDMParams(word=3)
    with pytest.raises(ValidationError):
        MDMParams(calibrated={"null_quantile": 0.9})  # a measured constant, not a parameter


def _glitched_start(fps: float, joint: str = "lelbow", frames: int = 2, angle: float = 1.6):
    """A walk whose ``joint`` is broken in its first ``frames`` input frames (as CMU 16_15's
    left arm), with the repaired texture taken from the clean walk and the texture cells that
    saw the glitch flagged."""
    from mocapflow.plugins.selfsim.paper.motion_words import motion_texture

    clean = synthetic_walk(240, fps=fps, seed=7)
    bad, j = _with_offset(clean, joint=joint, start=0, stop=frames, angle=angle)
    tex = motion_texture(bad)
    new24 = motion_texture(clean).q.copy()
    c = tex.joints.index(joint)
    flagged = np.zeros(tex.q.shape[:2], bool)
    flagged[:, c] = quat.geodesic_angle(tex.q[:, c], new24[:, c]) > 1e-6
    new24[~flagged] = tex.q[~flagged]  # the repair edits only the flagged cells
    return clean, bad, j, tex, new24, flagged


def test_carry_guard_never_turns_a_clean_input_frame_away_from_the_repair():
    from mocapflow.plugins.selfsim.paper.repair import apply_to_input

    clean, bad, j, tex, new24, flagged = _glitched_start(120.0)
    assert flagged.sum() == 1  # one 24-fps sample (input frame 0) caught the 2-frame glitch
    plain, changed_plain = apply_to_input(bad, tex, new24, flagged)
    guarded, changed = apply_to_input(bad, tex, new24, flagged, guard=True)

    def err(m):
        return quat.geodesic_angle(m.rotations[:, j], clean.rotations[:, j])

    # the unguarded carry turns the clean frames 2-4 the glitch's way; the guard leaves them
    assert err(plain)[2:5].min() > 0.3 and err(bad)[2:5].max() < 1e-6  # 0.96, 0.64, 0.32 rad
    assert not changed[2:, j].any() and np.array_equal(guarded.rotations[2:], bad.rotations[2:])
    # the broken frames are repaired (frame 0 is the sample: exactly; frame 1 nearer)
    assert err(guarded)[0] < 1e-6 and err(guarded)[1] < 0.5 * err(bad)[1]
    assert changed[:2, j].all() and changed.sum() == 2 and changed_plain.sum() > 2
    assert np.array_equal(
        guarded.rotations[:, np.arange(bad.n_joints) != j], bad.rotations[:, np.arange(bad.n_joints) != j]
    )


@pytest.mark.parametrize("joint", ["lelbow", "root"])
def test_carry_guard_changes_nothing_at_the_analysis_rate(joint):
    from mocapflow.plugins.selfsim.paper.repair import apply_to_input

    clean, bad, j, tex, new24, flagged = _glitched_start(24.0, joint=joint, frames=6, angle=0.8)
    plain, changed_plain = apply_to_input(bad, tex, new24, flagged)
    guarded, changed = apply_to_input(bad, tex, new24, flagged, guard=True)
    assert changed_plain[:6, j].all() and np.array_equal(changed, changed_plain)
    assert np.array_equal(guarded.rotations, plain.rotations)
