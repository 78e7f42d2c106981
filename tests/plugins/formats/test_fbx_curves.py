"""FBX animation curves: the vectorised tangents and evaluation of ``_fbx_curves`` against
the per-key twin of ``tests/naive/fbx_curves.py``, and the FBX reader against ufbx on the
ufbx test corpus (skipped without ufbx or the corpus; ufbx runs in a subprocess)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest

from mocapflow.plugins.formats import _fbx_curves as fc

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from naive import fbx_curves as naive

KTPS = 46_186_158_000
FLAG_CHOICES = [
    0x4,  # linear
    0x2,  # constant
    0x2 | 0x100,  # constant next
    0x8 | 0x400,  # cubic user
    0x8 | 0x400 | 0x800,  # cubic user broken
    0x8 | 0x100,  # cubic auto
    0x8 | 0x100 | 0x1000,  # auto clamp
    0x8 | 0x100 | 0x2000,  # auto time independent
    0x8 | 0x100 | 0x4000,  # auto progressive clamp
    0x8 | 0x200,  # TCB
    0x8 | 0x400 | 0x1000000 | 0x2000000,  # user, weighted both sides
]


def _random_curve(rng: np.random.Generator, n: int):
    ticks = np.cumsum(rng.integers(KTPS // 240, KTPS // 4, size=n)) - KTPS // 2
    values = rng.normal(0, 30, size=n).astype(np.float32).astype(np.float64)
    values[rng.random(n) < 0.2] = values[0]  # flat stretches for the clamps
    flags = np.array([FLAG_CHOICES[k] for k in rng.integers(0, len(FLAG_CHOICES), n)], dtype=np.uint32)
    data = np.zeros((n, 4), dtype=np.float32)
    data[:, :2] = rng.normal(0, 50, size=(n, 2))
    tcb = (flags & 0x200) != 0
    data[tcb, :3] = rng.uniform(-0.9, 0.9, size=(int(tcb.sum()), 3))
    w = rng.integers(500, 5000, size=(n, 2)).astype(np.uint32)  # weights 0.05-0.5
    weighted = (flags & 0x1000000) != 0
    data[weighted, 2] = (w[weighted, 0] | (w[weighted, 1] << 16)).view(np.float32)
    return ticks, values, flags, data


@pytest.mark.parametrize("seed", range(16))
def test_tangents_and_values_equal_the_per_key_twin(seed):
    rng = np.random.default_rng(seed)
    ticks, values, flags, data = _random_curve(rng, int(rng.integers(1, 12)))
    if seed >= 12:  # linear keys only: the fast path of baked takes
        flags[:] = 0x4
    c = fc.prepare(ticks, values, flags, data, KTPS)
    ref = naive.keys(ticks / KTPS, values, flags, data)
    for k, r in enumerate(ref):
        assert c.kind[k] == {"prev": fc.K_PREV, "next": fc.K_NEXT, "linear": fc.K_LINEAR, "cubic": fc.K_CUBIC}[r[2]]
        got = (c.left_dx[k], c.left_dy[k], c.right_dx[k], c.right_dy[k])
        np.testing.assert_allclose(got, r[3:], rtol=1e-6, atol=1e-9)
    modes = ["constant", "slope", "repeat", "relative", "mirror"]
    c.pre = (modes[seed % 5], [-1, 2][seed % 2])
    c.post = (modes[(seed + 2) % 5], [-1, 1][seed % 2])
    span = c.times[-1] - c.times[0]
    times = np.concatenate([rng.uniform(c.times[0] - 3 * span - 0.5, c.times[-1] + 3 * span + 0.5, 200), c.times])
    got = fc.evaluate(c, times)
    want = [naive.value(ref, t, c.pre, c.post, KTPS) for t in times]
    finite = np.isfinite(want)
    np.testing.assert_allclose(got[finite], np.asarray(want)[finite], rtol=1e-7, atol=1e-6)


def _corpus() -> Path | None:
    p = Path(os.environ.get("MOCAPFLOW_UFBX_DATA", Path(__file__).resolve().parents[2] / "data" / "ufbx"))
    return p if p.is_dir() else None


#: Maya, 3ds Max, MotionBuilder and Blender files of the ufbx corpus with animation:
#: InheritType Rrs (HumanIK), every interpolation and tangent mode, every extrapolation.
PARITY_FILES = [
    "maya_human_ik_7400_binary.fbx",
    "maya_anim_interpolation_7700_binary.fbx",
    "maya_auto_clamp_7700_binary.fbx",
    "maya_tangent_spline_7700_binary.fbx",
    "maya_tangent_clamped_7700_binary.fbx",
    "maya_anim_extrapolation_7700_binary.fbx",
    "maya_slime_7500_binary.fbx",
    "max_transformed_skin_7500_binary.fbx",
    "motionbuilder_extrapolation_mirror_count_7700_binary.fbx",
    "motionbuilder_extrapolation_relative_count_7700_binary.fbx",
    "motionbuilder_extrapolation_slope_7700_binary.fbx",
    "motionbuilder_tangent_velocity_split_7700_binary.fbx",
    "blender_293_barbarian_7400_binary.fbx",
]


@pytest.mark.parametrize("name", PARITY_FILES)
def test_reader_equals_ufbx(name):
    corpus = _corpus()
    if corpus is None or not (corpus / name).exists():
        pytest.skip("ufbx test corpus absent (set MOCAPFLOW_UFBX_DATA to github.com/ufbx/ufbx data/)")
    sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
    import _ufbx_ref
    from fbx_parity import compare

    if not _ufbx_ref.available():
        pytest.skip("ufbx is not installed (pip install ufbx)")
    r = compare(corpus / name, max_frames=40)
    assert r["err"] <= 1e-4
    assert r["fps"] == pytest.approx(r["ufbx_fps"], rel=1e-6)
    assert r["frames"] == r["ufbx_frames"]


@pytest.mark.parametrize("order", ["xyz", "xzy", "yzx", "yxz", "zxy", "zyx"])
def test_euler_closed_form_equals_the_generic_product(order):
    from mocapflow.framework import quaternions as quat
    from mocapflow.plugins.formats.fbx import _euler

    ang = np.random.default_rng(3).uniform(-400, 400, size=(50, 3))
    idx = ["xyz".index(a) for a in order]
    want = quat.from_euler(ang[:, idx[::-1]], order[::-1], degrees=True)
    got = _euler(ang, order)
    assert np.abs(np.abs((got * want).sum(axis=1)) - 1).max() < 1e-12
