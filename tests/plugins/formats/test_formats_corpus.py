"""Every AMC and BVH file of the real corpus parses, with the files' own frame counts,
the required canonical joints and plausible metres (reads the whole corpus once, ~5 s)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from conftest import corpus_path

from mocapflow.framework.joints import CANONICAL_JOINTS, REQUIRED_JOINTS
from mocapflow.plugins.formats.asf_amc import read_amc
from mocapflow.plugins.formats.bvh import read_bvh

FEET = [CANONICAL_JOINTS.index(j) for j in ("lankle", "rankle", "ltoes", "rtoes")]
HEADTOP = CANONICAL_JOINTS.index("headtop")
_FRAME_LINE = re.compile(rb"^[ \t]*\d+[ \t]*\r?$", re.MULTILINE)


def summary(m) -> dict:
    p = m.canonical_positions()
    feet = np.nanmin(p[:, FEET, 1], axis=1)
    return {
        "frames": m.n_frames,
        "missing": [j for j in REQUIRED_JOINTS if j not in m.skeleton.canonical],
        "foot_median": float(np.median(feet)),
        "height": float(np.nanmax(p[:, HEADTOP, 1] - feet)),
        "finite": bool(np.isfinite(m.positions).all()),
    }


@pytest.fixture(scope="module")
def amc_files() -> dict[Path, dict]:
    files = sorted(corpus_path("cmu", "amc").glob("*/*.amc")) + sorted(corpus_path("hdm05", "amc").glob("*/*.amc"))
    out = {}
    for f in files:
        m = read_amc(f)
        s = summary(m)
        rest = np.zeros((m.skeleton.n_joints, 3))
        for j in range(1, m.skeleton.n_joints):
            rest[j] = rest[m.skeleton.parents[j]] + m.skeleton.offsets[j]
        s["rest_height"] = float(rest[:, 1].max() - rest[:, 1].min())
        s["blocks"] = len(_FRAME_LINE.findall(f.read_bytes()))
        out[f] = s
    return out


@pytest.fixture(scope="module")
def bvh_files() -> dict[Path, dict]:
    out = {}
    for f in sorted(corpus_path("bvh").glob("*/*.bvh")):
        s = summary(read_bvh(f))
        s["declared"] = int(re.search(rb"Frames:\s*(\d+)", f.read_bytes()).group(1))
        out[f] = s
    return out


def test_amc_corpus_counts(amc_files: dict[Path, dict]) -> None:
    assert len(amc_files) == 169
    assert all(s["frames"] == s["blocks"] for s in amc_files.values())
    assert sum(s["frames"] for s in amc_files.values()) == 110_109


def test_amc_corpus_joints_and_metres(amc_files: dict[Path, dict]) -> None:
    for f, s in amc_files.items():
        assert not s["missing"] and s["finite"], f
        assert 1.4 <= s["rest_height"] <= 2.1, (f, s)  # standing height of the ASF rest pose
        assert 1.25 <= s["height"] <= 2.1, (f, s)
        # feet near the floor most of the time (subject 03 walks on raised terrain, ~0.3 m)
        assert -0.05 <= s["foot_median"] <= 0.35, (f, s)


def test_bvh_corpus(bvh_files: dict[Path, dict]) -> None:
    assert len(bvh_files) == 32
    for f, s in bvh_files.items():
        assert s["frames"] == s["declared"], f
        assert not s["missing"] and s["finite"], f
        assert 1.25 <= s["height"] <= 2.1, (f, s)
        assert -0.05 <= s["foot_median"] <= 0.1, (f, s)
