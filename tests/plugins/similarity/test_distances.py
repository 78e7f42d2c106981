"""Distance measures (plugins/similarity/distances.py) and the Fig. 2 correlation study."""

from __future__ import annotations

import numpy as np
import pytest
from naive.distances import point_cloud_distance as naive_pc
from scipy.stats import spearmanr

from mocapflow.framework import MotionDatabase
from mocapflow.framework import quaternions as quat
from mocapflow.framework.testing import synthetic_motion
from mocapflow.plugins.similarity.applications.correlation import DistanceCorrelationStudy, spearman_rows
from mocapflow.plugins.similarity.knn.distances import PoseMeasures, point_cloud_distance


def test_point_cloud_distance_is_rigid_2d_invariant_and_matches_grid_search():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(30, 3))
    th = 1.1
    r = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
    moved = a @ r.T + np.array([3.0, 0.0, -2.0])
    assert point_cloud_distance(a[None], moved[None])[0] < 1e-6
    b = rng.normal(size=(30, 3))
    got = point_cloud_distance(a[None], b[None])[0]
    assert got == pytest.approx(naive_pc(a, b), rel=1e-6, abs=1e-6)
    # a vertical shift is not aligned away
    up = a + np.array([0.0, 0.5, 0.0])
    assert point_cloud_distance(a[None], up[None])[0] == pytest.approx(0.5 * np.sqrt(30))


def test_pose_measures_basic_properties():
    db = MotionDatabase([synthetic_motion(40, seed=1), synthetic_motion(1, seed=2), synthetic_motion(30, seed=3)])
    pm = PoseMeasures(db)
    js = np.arange(db.n_frames)
    for m in ("D_quat", "D_euler", "D_pc1", "D_pc11", "D_wb"):
        d = pm.distance(m, 5, js)
        assert d.shape == (db.n_frames,) and np.all(d >= 0) and d[5] == pytest.approx(0, abs=1e-6)
        np.testing.assert_allclose(pm.distance(m, 50, np.array([5])), d[[50]], rtol=1e-9, atol=1e-9)  # symmetric
    # windows clamp at clip edges: the one-frame clip's window is that frame repeated
    assert pm.window_rows(np.array([40]), 11).tolist() == [[40] * 11]
    assert pm.window_rows(np.array([0]), 5).tolist() == [[0, 0, 0, 1, 2]]
    # D_quat is the root of summed squared geodesic angles of the non-root joints
    q = np.concatenate([m.rotations[:, 1:] for m in db.motions])
    want = np.sqrt((quat.geodesic_angle(q[5], q[60]) ** 2).sum())
    assert pm.distance("D_quat", 5, np.array([60]))[0] == pytest.approx(want)
    # D_euler: synthetic rotations were built from zxy Euler angles of the same joints
    assert np.isfinite(pm.euler).all() and pm.euler.shape[1] == 3 * (db.motions[0].n_joints - 1)


def test_euler_dofs_reproduce_amc_values():
    from conftest import corpus_path

    from mocapflow.plugins.formats.asf_amc import read_amc
    from mocapflow.plugins.similarity.knn.distances import euler_dofs

    f = sorted(corpus_path("hdm05", "amc").glob("*/*.amc"))[0]
    m = read_amc(f).slice(0, 3)
    lines = f.read_text(encoding="latin-1").replace("\r", "").split("\n")
    start = lines.index("1") + 1
    from mocapflow.plugins.similarity.knn.distances import angle_joints

    by_bone = {}
    for ln in lines[start:]:
        if ln.strip() == "2":
            break
        name, *nums = ln.split()
        by_bone[name] = [float(v) for v in nums]
    vals = [v for j in angle_joints(m) for v in by_bone[m.skeleton.names[j]]]
    np.testing.assert_allclose(np.degrees(euler_dofs(m)[0]), vals, atol=1e-4)


def test_spearman_rows_matches_scipy():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(5, 40)), rng.normal(size=(5, 40))
    b[0] = a[0] ** 3
    b[1, :20] = 1.0  # ties
    got = spearman_rows(a, b)
    want = [spearmanr(a[i], b[i])[0] for i in range(5)]
    np.testing.assert_allclose(got, want, atol=1e-12)
    assert got[0] == pytest.approx(1.0)


def test_correlation_study_small(tmp_path):
    db = MotionDatabase([synthetic_motion(120, seed=s) for s in range(4)])
    study = DistanceCorrelationStudy(
        samples=12, k=16, measures=("D_quat", "D_pc1", "F_E15", "F_E30", "F_E15x3", "F_pca8")
    )
    rows, cols, rho, std, n = study.study(db, rows=("F_E15", "D_pc1"))
    assert rho.shape == (2, 6) and rows == ("F_E15", "D_pc1")
    assert rho[0, 2] == 1.0 and rho[1, 1] == 1.0 and np.all(n == 12)
    assert np.all(np.abs(rho) <= 1.0) and rho[0, 3] > 0.5  # F15 ~ F30 even on synthetic motion
    from mocapflow.plugins.similarity.applications.correlation import plot_heatmap

    png = plot_heatmap(rows, cols, rho, tmp_path / "c.png")
    assert png is not None and png.stat().st_size > 1000
