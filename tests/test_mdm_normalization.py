"""Row/cell normalisations of the MDM (§3.4): the paper's row mean and the robust scales."""
from __future__ import annotations

import numpy as np
import pytest
from naive.cleaning import synthetic_walk

from mocapflow.framework import quaternions as quat
from mocapflow.framework.errors import DataError
from mocapflow.plugins.selfsim.mdm import MDMParams, digression_from_outer, digression_map, knn_spread, row_scale


def _random_quats(rng, n, spread):
    axis = rng.standard_normal((n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    base = quat.from_axis_angle(np.array([0.3, 0.9, 0.1]) / np.linalg.norm([0.3, 0.9, 0.1]), np.array(0.7))
    q = quat.mul(np.broadcast_to(base, (n, 4)), quat.from_axis_angle(axis, spread * rng.standard_normal(n)))
    return q * rng.choice([-1.0, 1.0], size=(n, 1))  # sign flips must not matter


def test_knn_spread_is_the_rms_half_angle_about_the_chordal_mean():
    rng = np.random.default_rng(0)
    outer = np.zeros((3, 2, 4, 4))
    count = np.zeros((3, 2), np.int64)
    want = np.zeros((3, 2))
    for t in range(3):
        for j in range(2):
            if (t, j) == (2, 1):
                continue  # an uncovered cell
            n = 1 + 4 * t + j
            q = _random_quats(rng, n, 0.1 + 0.3 * j)
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


def test_row_scales_follow_their_definitions():
    rng = np.random.default_rng(1)
    diff = np.abs(rng.standard_normal((50, 3))) * 0.2
    diff[:, 2] = 0.0  # a joint that never digresses
    q = quat.normalize(rng.standard_normal((50, 3, 4)))
    spread = np.abs(rng.standard_normal((50, 3))) * 0.1
    p = MDMParams(normalization="median", robust_factor=2.5, noise_floor=0.03)
    np.testing.assert_allclose(row_scale(diff, q, spread, p)[0], 2.5 * np.maximum(np.median(diff, 0), 0.03))
    p = MDMParams(normalization="spread", spread_factor=2.0, noise_floor=0.03)
    np.testing.assert_allclose(row_scale(diff, q, spread, p), 2.0 * np.sqrt(spread ** 2 + 0.03 ** 2))
    p = MDMParams(normalization="mean")
    np.testing.assert_allclose(row_scale(diff, q, spread, p)[0], np.maximum(diff.mean(0), 0.01))
    with pytest.raises(DataError):
        row_scale(diff, q, None, MDMParams(normalization="spread"))
    # the last step of §3.4, from a given difference: MDM = 1 - exp(-(diff / scale)^2), 0 on a zero scale
    p = MDMParams(normalization="median", noise_floor=0.0)
    mdm = digression_from_outer(q, np.zeros((0, 4, 4)), np.zeros((0,), np.int64), p, difference=diff, spread=spread)[3]
    s = p.robust_factor * np.median(diff[:, :2], 0)
    np.testing.assert_allclose(mdm[:, :2], 1 - np.exp(-(diff[:, :2] / s) ** 2))
    assert np.all(mdm[:, 2] == 0)


@pytest.fixture(scope="module")
def spiked():
    """A clean synthetic walk with one single-frame 40 degree spike on the left knee."""
    clean = synthetic_walk(360, seed=7)
    rot = clean.rotations.copy()
    j = clean.skeleton.canonical["lknee"]
    rot[180, j] = quat.mul(rot[180, j], quat.from_axis_angle(np.array([1.0, 0, 0]), np.array(np.deg2rad(40.0))))
    bad = clean.with_arrays(rotations=rot)
    return bad, digression_map(bad, params=MDMParams(normalization="mean"))


@pytest.mark.parametrize("norm", ["median", "spread"])
def test_robust_scales_flag_the_spike_and_almost_nothing_else(spiked, norm):
    bad, lit = spiked
    c = lit.joints.index("lknee")
    p = MDMParams(normalization=norm)
    mdm = digression_from_outer(lit.texture.q, np.zeros((0, 4, 4)), np.zeros((0,), np.int64), p,
                                difference=lit.difference, spread=lit.spread)[3]
    flagged = mdm > p.threshold
    assert flagged[180, c]
    # nearly nothing else: under 0.2 % of the other cells (the paper's row mean flags tens of percent)
    others = flagged.copy()
    others[179:182, c] = False
    assert others.mean() < 0.002
    paper = lit.mdm > p.threshold
    assert paper.mean() > 10 * max(others.mean(), 1e-4)


def test_digression_map_reports_the_spread(spiked):
    _, lit = spiked
    assert lit.spread is not None and lit.spread.shape == lit.difference.shape
    assert np.all(lit.spread >= 0) and np.all(lit.spread <= np.pi)


def test_default_decides_calibrated_and_the_paper_stays_available():
    p = MDMParams()
    assert p.mode == "calibrated" and p.normalization == "mean" and p.threshold == 0.5
    assert MDMParams(mode="paper").mode == "paper"
    assert MDMParams(normalization="median").robust_factor == 2.5
