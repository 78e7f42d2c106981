"""The calibrated cleaner: kinematic helpers against naive references, bounded repair, the
paper mode kept, the density injector, and what ``mocapflow clean`` writes (the detectors,
the null and the test: tests/plugins/selfsim/test_mdm_null.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from naive.cleaning import synthetic_walk
from naive.cleaning_cues import (
    naive_acceleration,
    naive_mirror_gain,
    naive_window_median,
    naive_window_min,
)

from mocapflow.framework import quaternions as quat
from mocapflow.plugins.selfsim.calibrated import cues
from mocapflow.plugins.selfsim.calibrated.detectors import DETECTORS
from mocapflow.plugins.selfsim.cleaner import MDMCleaner
from mocapflow.plugins.selfsim.evaluation.error_injection import inject_at_density


def _rand_quats(rng, shape):
    return quat.make_continuous(quat.normalize(rng.standard_normal(shape + (4,))), axis=0)


def test_cues_match_naive_references():
    rng = np.random.default_rng(0)
    q = _rand_quats(rng, (12, 7))
    np.testing.assert_allclose(cues.acceleration(q), naive_acceleration(q), atol=1e-7)
    x = rng.random((11, 3))
    for half in (1, 2):
        np.testing.assert_array_equal(cues.window_min(x, half), naive_window_min(x, half))
    joints = ["lshoulder", "lelbow", "lwrist", "rshoulder", "relbow", "rwrist", "head"]
    mq = _rand_quats(rng, (12, 7))
    np.testing.assert_allclose(
        cues.mirror_gain(q, mq, joints),
        naive_mirror_gain(q, mq, joints, cues.MIRROR_CHAINS, np.deg2rad(5.0)),
        atol=1e-7,
    )
    for half in (1, 3):
        np.testing.assert_allclose(cues.window_median(x, half), naive_window_median(x, half))


def test_mirror_gain_sees_a_swap_only_where_it_is():
    walk = synthetic_walk(120, seed=2)
    q = walk.rotations
    joints = [None] * walk.n_joints
    for name, j in walk.skeleton.canonical.items():
        joints[j] = name
    c = walk.skeleton.canonical
    bad = q.copy()
    left = [c[j] for j in ("lshoulder", "lelbow", "lwrist")]
    right = [c[j] for j in ("rshoulder", "relbow", "rwrist")]
    bad[40:60, left] = cues.mirror(q[40:60, right])
    bad[40:60, right] = cues.mirror(q[40:60, left])
    gain = cues.mirror_gain(bad, q, joints)  # the clean motion as the consensus
    assert gain[40:60, left + right].max(1).min() > 0.2 and np.all(gain[:40] == 0) and np.all(gain[60:] == 0)


def test_swap_back_needs_a_swap_and_undoes_it():
    from mocapflow.plugins.selfsim.calibrated.bounded_repair import swap_frames

    walk = synthetic_walk(120, seed=2)
    names = [None] * walk.n_joints
    for name, j in walk.skeleton.canonical.items():
        names[j] = name
    q = quat.make_continuous(walk.rotations, axis=0)
    c = walk.skeleton.canonical
    left = [c[j] for j in ("lshoulder", "lelbow", "lwrist")]
    right = [c[j] for j in ("rshoulder", "relbow", "rwrist")]
    bad = q.copy()
    bad[40:60, left] = cues.mirror(q[40:60, right])
    bad[40:60, right] = cues.mirror(q[40:60, left])
    flags = np.ones(q.shape[:2], bool)
    runs = swap_frames(bad, q, names, flags, 0.3)
    arm = [(a, b) for lc, rc, a, b in runs if set(lc.tolist()) == set(left)]
    assert arm and arm[0][0] <= 41 and arm[0][1] >= 59
    # the clean walk against a consensus that looks mirrored: swapping back would add jumps, refused
    fake = q.copy()
    fake[40:60, left] = cues.mirror(q[40:60, right])
    fake[40:60, right] = cues.mirror(q[40:60, left])
    assert not [r for r in swap_frames(q, fake, names, flags, 0.3) if set(r[0].tolist()) == set(left)]


def test_density_injection_is_seeded_and_reaches_the_density():
    clean = synthetic_walk(480, seed=1)
    a, mask_a, err_a = inject_at_density(clean, 0.125, seed=3)
    b, mask_b, err_b = inject_at_density(clean, 0.125, seed=3)
    assert np.array_equal(a.rotations, b.rotations) and err_a == err_b and np.array_equal(mask_a, mask_b)
    starts = np.arange(0, len(mask_a) - 14, 5)
    share = np.mean([mask_a[s : s + 15].any() for s in starts])
    assert 0.125 <= share < 0.3
    spans = sorted((e.start, e.end) for e in err_a)
    assert all(s1 >= e0 for (_, e0), (s1, _) in zip(spans, spans[1:], strict=False))  # never overlapping
    for e in err_a:
        lo, hi = {"spike": (1, 3), "offset": (6, 18), "freeze": (12, 24), "noise": (8, 16), "swap": (12, 24)}[e.kind]
        assert lo <= e.end - e.start <= hi
        if e.kind == "spike":
            assert 30 <= e.magnitude <= 90


@pytest.fixture(scope="module")
def walks():
    clean = synthetic_walk(240, seed=5, name="take")
    rot = clean.rotations.copy()
    j = clean.skeleton.canonical["lknee"]
    rot[120:122, j] = quat.mul(rot[120:122, j], quat.from_axis_angle(np.array([1.0, 0, 0]), np.array(np.deg2rad(60.0))))
    return clean, clean.with_arrays(rotations=rot, name="take"), j


def test_calibrated_cleaner_leaves_a_clean_take_alone_and_repairs_a_spike(walks):
    clean, bad, j = walks
    context = [synthetic_walk(240, seed=s, name=f"ctx{s}") for s in (6, 7)]
    cleaner = MDMCleaner(write_bvh=False, heatmaps=False)
    assert cleaner.params.mode == "calibrated"
    ok = cleaner.clean(clean, context)
    n_cells = clean.n_frames * len(ok.analysis.joints)
    assert ok.edits.num_rows <= 0.01 * n_cells
    assert ok.edits.num_rows == 0 or ok.edits["edit_deg"].to_numpy().max() <= 15.0
    out = cleaner.clean(bad, context)
    assert out.calibration.source == "context"
    assert {c.split("[")[0] for c in out.calibration.clips} <= {"ctx6", "ctx7"}
    c = out.analysis.joints.index("lknee")
    assert out.flags[120:122, c].any()
    assert set(out.cue[out.flags].tolist()) <= set(DETECTORS)
    err0 = quat.geodesic_angle(bad.rotations[120:122, j], clean.rotations[120:122, j])
    err1 = quat.geodesic_angle(out.cleaned.rotations[120:122, j], clean.rotations[120:122, j])
    assert err1.max() < 0.5 * err0.min()
    # never farther from the KNN consensus than before, on any cell
    res = out.analysis
    before = quat.geodesic_angle(res.texture.q, res.mean_texture)
    after = quat.geodesic_angle(out.repaired, res.mean_texture)
    assert np.all(after <= before + 1e-9)
    assert np.array_equal(out.repaired[~out.edited], res.texture.q[~out.edited])
    assert {"cue", "edit_deg"} <= set(out.edits.column_names)


def test_paper_mode_is_the_literal_mdm(walks):
    _, bad, _ = walks
    paper = MDMCleaner(mode="paper", write_bvh=False, heatmaps=False)
    assert paper.params.threshold == 0.5
    out = paper.clean(bad)
    res = out.analysis
    m = res.difference / np.maximum(res.difference.mean(axis=0, keepdims=True), 0.01)
    np.testing.assert_allclose(res.mdm, 1 - np.exp(-(m**2)))
    np.testing.assert_array_equal(out.flags, res.mdm > 0.5)


def _cli(tmp_path, *extra):
    from pathlib import Path

    from mocapflow.framework.cli import main

    repo = Path(__file__).resolve().parents[3]
    take = repo / "examples" / "data" / "cmu" / "16" / "16_15.amc"
    if not take.is_file():
        pytest.skip("bundled example data missing")
    return main(["clean", str(take), *extra])


def test_clean_refuses_an_unknown_output_kind_before_the_work(tmp_path, capsys):
    assert _cli(tmp_path, "--output", str(tmp_path / "x.fbx")) == 2
    assert ".bvh or .amc" in capsys.readouterr().err
    assert not (tmp_path / "x.fbx").exists()


def test_clean_writes_amc_with_its_asf_into_a_new_folder_and_a_report(tmp_path):
    pytest.importorskip("matplotlib")
    from mocapflow.plugins.formats.asf_amc import read_amc

    dest = tmp_path / "new" / "deeper" / "clean.amc"
    assert _cli(tmp_path, "--output", str(dest), "--report", str(tmp_path / "rep")) == 0
    assert dest.is_file() and dest.with_suffix(".asf").is_file()
    assert read_amc(dest).n_frames > 0
    assert not list(dest.parent.glob(".*tmp*"))
    summary = json.loads((tmp_path / "rep" / "summary.json").read_text())
    assert {"flagged_per_joint", "largest_edits", "calibration", "edited_share"} <= set(summary)
    assert "seconds" not in summary


def test_clean_honours_block(tmp_path, capsys):
    """With the formats plugin blocked, the command finds no reader: it used the CLI's
    plugin manager, not a default one."""
    from pathlib import Path

    from mocapflow.framework.cli import main

    take = Path(__file__).resolve().parents[3] / "examples" / "data" / "cmu" / "16" / "16_15.amc"
    if not take.is_file():
        pytest.skip("bundled example data missing")
    code = main(
        ["--block", "mocapflow.plugins.formats.plugin", "clean", str(take), "--output", str(tmp_path / "c.bvh")]
    )
    assert code == 2 and "no registered reader" in capsys.readouterr().err


def test_clean_uses_the_plugin_manager_the_cli_built():
    import argparse

    from mocapflow.framework.commands import context_of

    sentinel = object()
    assert context_of(argparse.Namespace(plugin_manager=sentinel)).plugin_manager is sentinel
    ctx = context_of(argparse.Namespace(block=["mocapflow.plugins.matchers.plugin"], no_entry_points=True))
    assert ctx.plugin_manager.is_blocked("mocapflow.plugins.matchers.plugin")


def test_cleaner_provenance_is_deterministic(tmp_path):
    """Two identical runs give identical step summaries (no timings, no temporary paths)."""
    pytest.importorskip("matplotlib")
    from types import SimpleNamespace

    from mocapflow.framework.database import MotionDatabase
    from mocapflow.framework.plugins import default_registries
    from mocapflow.framework.steps import run_cleaner

    db = MotionDatabase([synthetic_walk(120, seed=9, name="w")])
    inputs = {"motions": SimpleNamespace(motions=lambda: db)}
    cleaner = MDMCleaner()
    outs = []
    for k in range(2):
        out_dir = tmp_path / f"run{k}" / ".tmp-step"
        out_dir.mkdir(parents=True)
        ctx = SimpleNamespace(
            progress=lambda it, **_: it,
            step_id="mdm",
            out_dir=out_dir,
            registries=default_registries(),
            log=SimpleNamespace(info=lambda *_: None),
            map_clips=lambda fn, ds, with_ids=False, **_: [
                fn(m, int(i)) for i, m in zip(ds.motions().clip_ids, ds.motions().motions, strict=True)
            ],
        )
        outs.append(json.dumps(run_cleaner(cleaner, inputs, ctx).summary, sort_keys=True))
    assert outs[0] == outs[1]
    assert str(tmp_path) not in outs[0]


def _smooth_track(t: int = 80, seed: int = 0) -> np.ndarray:
    """One joint turning smoothly (a few degrees a frame about a slowly changing axis), (t, 4)."""
    rng = np.random.default_rng(seed)
    ang = np.deg2rad(30.0) * np.sin(np.linspace(0.0, 4.0 * np.pi, t))
    axis = np.array([1.0, 0.3, 0.0]) + 0.1 * rng.standard_normal(3)
    return quat.from_axis_angle(np.broadcast_to(axis / np.linalg.norm(axis), (t, 3)), ang)


def test_native_edges_snap_to_the_input_frame_that_jumps():
    from mocapflow.plugins.selfsim.paper.repair import _snap_edges

    t_in, r = 100, 5
    x = np.arange(t_in) / r  # analysis frame of each input frame (24 fps from 120)
    track = _smooth_track(t_in)
    off = quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), np.deg2rad(40.0))
    bad = track.copy()
    bad[37:63] = quat.mul(bad[37:63], off)  # starts 2 input frames after sample 7, ends 3 after 12
    flagged = np.zeros(20, bool)
    flagged[8:13] = True  # analysis samples 8..12 (input 40..60) hold the offset
    delta = np.tile(quat.identity(()), (20, 1))
    delta[flagged] = quat.conjugate(off)
    d = np.tile(quat.identity(()), (t_in, 1))
    i0 = np.minimum(np.floor(x).astype(int), 19)
    i1 = np.minimum(i0 + 1, 19)
    d = quat.slerp(np.where(flagged[i0][:, None], delta[i0], d), np.where(flagged[i1][:, None], delta[i1], d), x - i0)
    left = _snap_edges(d, bad, flagged, delta, x)
    fixed = quat.mul(bad, d)
    assert np.degrees(quat.geodesic_angle(fixed, track)).max() < 1e-4  # every input frame exact
    assert left[36] and not left[37] and left[63] and not left[62]


def test_a_context_too_small_or_unlike_falls_back_to_the_shipped_null_and_says_so(walks, caplog):
    clean, bad, _ = walks
    short = synthetic_walk(240, seed=6, name="ctx6")
    short = short.slice(0, int(2 * short.fps))  # 2 s of context: too few words like the take
    with caplog.at_level("WARNING", logger="mocapflow.cleaning"):
        out = MDMCleaner(write_bvh=False, heatmaps=False).clean(bad, [short])
    assert out.calibration.source == "shipped" and out.calibration.fallback.startswith("context")
    assert out.calibration.summary()["fallback"] == out.calibration.fallback
    assert "take: context" in caplog.text and "null shipped with the package" in caplog.text
