"""benchmarks/corpus.py: mirroring is exact on positions; augmentation is seeded and exact in size."""

from __future__ import annotations

import sys

import numpy as np
from conftest import REPO, corpus_path

from mocapflow.framework.testing import synthetic_motion

sys.path.insert(0, str(REPO / "benchmarks"))
import corpus


def _check_mirror(m):
    mm = corpus.mirror_motion(m)
    p = corpus.mirror_partners(m.skeleton.names)
    assert not np.array_equal(p, np.arange(len(p)))
    np.testing.assert_allclose(mm.positions, m.positions[:, p] * np.array([-1.0, 1.0, 1.0]), atol=1e-9)
    back = corpus.mirror_motion(mm)
    np.testing.assert_allclose(back.positions, m.positions, atol=1e-9)


def test_mirror_synthetic():
    _check_mirror(synthetic_motion(20, seed=1))


def test_mirror_real_asf_and_augmentation(tmp_path):
    from mocapflow.framework import MotionDatabase
    from mocapflow.plugins.formats.asf_amc import read_amc

    f = sorted(corpus_path("hdm05", "amc").glob("*/*.amc"))[0]
    m = read_amc(f).slice(0, 40)
    _check_mirror(m)
    base = MotionDatabase([m, m.slice(0, 7)])
    a = corpus._build_augmented(base, 200, 30.0, seed=3)
    b = corpus._build_augmented(base, 200, 30.0, seed=3)
    assert sum(x.n_frames for x in a) == 200
    np.testing.assert_array_equal(a[-1].rotations, b[-1].rotations)
    corpus._save(a, tmp_path / "db")
    back = corpus._load(tmp_path / "db")
    assert back.n_frames == 200
    np.testing.assert_allclose(back.canonical_positions(), MotionDatabase(a).canonical_positions(), atol=1e-4)
