"""Error injection, baselines and the cleaning evaluation harness; the clean pipeline and CLI."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from naive.cleaning import synthetic_walk

from mocapflow.framework import quaternions as quat
from mocapflow.plugins.selfsim.evaluation.clean_eval import CleaningEvaluationParams, evaluate_category
from mocapflow.plugins.selfsim.evaluation.error_injection import ERROR_KINDS, apply_error, mirror
from mocapflow.plugins.selfsim.evaluation.scores import RotationBaselines, _log_norm_sq, rotation_vectors, scores

REPO = Path(__file__).resolve().parents[3]


def test_each_kind_touches_only_its_span():
    clean = synthetic_walk(100, seed=2)
    c = clean.skeleton.canonical
    for kind in ERROR_KINDS:
        rot = clean.rotations.copy()
        joints = (c["lshoulder"], c["lelbow"], c["rshoulder"], c["relbow"]) if kind == "swap" else (c["lknee"],)
        apply_error(rot, clean, kind, 40, 50, joints, 40.0, np.random.default_rng(0))
        diff = quat.geodesic_angle(rot, clean.rotations) > 1e-6
        assert not diff[:40].any() and not diff[50:].any(), kind
        if kind != "freeze":
            assert diff[40:50, list(joints)].any(), kind
    q = quat.normalize(np.array([0.9, 0.1, 0.3, -0.2]))
    assert np.allclose(mirror(mirror(q)), q)


def test_baselines_flag_what_clean_data_never_does():
    clean = [synthetic_walk(200, seed=s).rotations[:, :4] for s in (1, 2)]
    base = RotationBaselines(clean)
    assert not base.limits(clean[0]).any() and not base.derivative(clean[0]).any()
    bad = clean[0].copy()
    bad[50, 1] = quat.mul(bad[50, 1], quat.from_axis_angle(np.array([0, 1.0, 0]), np.array(2.5)))
    assert base.limits(bad)[50, 1] and base.derivative(bad)[50, 1]
    rv = rotation_vectors(quat.from_axis_angle(np.array([0, 0, 1.0]), np.array(0.7)))
    assert np.allclose(rv, [0, 0, 0.7])


def test_scores_and_eq2():
    truth = np.zeros((30, 2), bool)
    truth[10:12, 0] = True
    flagged = np.zeros_like(truth)
    flagged[11:13, 0] = True
    s = scores(flagged, truth, np.array([0, 5, 10, 15]), 15)
    assert (s["tp"], s["fp"], s["fn"]) == (1, 1, 1)
    assert s["word_tp"] == 3 and s["word_fp"] == 0
    q = quat.identity((30, 2))
    other = q.copy()
    other[10, 0] = quat.from_axis_angle(np.array([1.0, 0, 0]), np.array(0.4))
    assert _log_norm_sq(q, other)[10, 0] == pytest.approx(0.04)  # (half of 0.4 rad) squared


def test_harness_on_synthetic_walks():
    clips = [synthetic_walk(360, seed=s, name=f"w{s}") for s in range(4)]
    p = CleaningEvaluationParams(n_test=1, small_size=2, contexts=("small",), held_out={"locomotion": ()})
    rows, rep, kinds = evaluate_category("locomotion", clips, p, log=lambda *_: None)
    by = {(r["method"], r["context"]): r for r in rows}
    assert set(by) == {
        ("baseline_a_limits", "-"),
        ("baseline_b_derivative", "-"),
        ("baseline_c_both", "-"),
        ("mdm", "small"),
        ("mdm[paper]", "small"),
    }
    assert {"wj_recall", "wj_precision", "word_recall", "recall"} <= set(by[("mdm", "small")])
    assert by[("mdm[paper]", "small")]["recall"] >= by[("mdm", "small")]["recall"]
    r = {x["method"]: x for x in rep}
    assert r["mdm"]["clean_edited_share"] <= 0.01 and r["mdm"]["clean_max_edit_deg"] <= 30.0 + 1e-3
    assert r["mdm"]["cells_after"] < r["mdm"]["cells_before"]
    assert kinds and {"kind", "errors", "found"} <= set(kinds[0])


def test_clean_pipeline_and_cli(tmp_path, capsys):
    if not (REPO / "examples" / "data" / "cmu" / "16" / "16_15.amc").is_file():
        pytest.skip("bundled example data missing")
    pytest.importorskip("matplotlib")
    from mocapflow.framework.cli import main
    from mocapflow.framework.datasets import read_datasets
    from mocapflow.framework.runner import run_pipeline

    ws = tmp_path / "ws"
    run_pipeline(REPO / "pipelines" / "clean.yaml", workspace=ws, echo=lambda s: None)
    ds = read_datasets(ws)["mdm"]
    mdm = ds.table("data")
    assert set(mdm.column_names) >= {"clip_id", "frame", "joint", "joint_name", "value"}
    v = mdm["value"].to_numpy()
    assert v.min() >= 0 and v.max() <= 1
    assert (ds.path / "16_15.clean.bvh").is_file() and (ds.path / "16_15.mdm.png").is_file()
    take = REPO / "examples" / "data" / "cmu" / "16" / "16_15.amc"
    ctx = REPO / "examples" / "data" / "cmu" / "16" / "16_01.amc"
    out = tmp_path / "clean.bvh"
    assert (
        main(
            [
                "clean",
                str(take),
                "--context",
                str(ctx),
                "--output",
                str(out),
                "--report",
                str(tmp_path / "rep"),
                "--mode",
                "paper",
            ]
        )
        == 0
    )
    assert (
        out.is_file() and (tmp_path / "rep" / "mdm.parquet").is_file() and (tmp_path / "rep" / "summary.json").is_file()
    )
    from mocapflow.plugins.formats.bvh import read_bvh

    assert read_bvh(out).n_frames > 0
    # one unit in the message and the summary: input frames x joints, and what decided
    import json

    import pyarrow.parquet as pq

    said = capsys.readouterr().out
    summary = json.loads((tmp_path / "rep" / "summary.json").read_text())
    flagged = int(pq.read_table(tmp_path / "rep" / "mdm.parquet")["flagged"].to_numpy().sum())
    assert summary["flagged_cells"] == flagged and summary["decided_by"] == "MDM > 0.5"
    assert f"{flagged} input frames x joints flagged (MDM > 0.5)" in said and " at 120 fps " in said


def test_clean_eval_pipeline_plans():
    from mocapflow.framework.runner import plan_pipeline

    plan = plan_pipeline(REPO / "pipelines" / "clean-eval.yaml")
    assert [s.key for s in plan.steps][-1] == "analyses.clean_eval"
