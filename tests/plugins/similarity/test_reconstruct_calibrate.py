"""Per-performer marker offsets (reconstruct_calibrate.py): recovery on synthetic markers,
the CLI on a corpus C3D, error paths."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import corpus_path
from test_reconstruct import periodic_motion

from mocapflow.framework import DataError
from mocapflow.framework.markers import Markers
from mocapflow.plugins.similarity.applications.reconstruct import DEFAULT_MARKERS
from mocapflow.plugins.similarity.applications.reconstruct_calibrate import apply_offsets, calibrate, root_from_hips
from mocapflow.plugins.similarity.applications.reconstruct_markers import calibrated_control

JOINTS = (
    "lhip",
    "rhip",
    "head",
    "headtop",
    "lelbow",
    "lwrist",
    "relbow",
    "rwrist",
    "lknee",
    "lankle",
    "rknee",
    "rankle",
)


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def skin_markers(m, noise: float = 0.002, seed: int = 0):  # type: ignore[no-untyped-def]
    """Plug-in-Gait style markers a constant segment-frame vector off the joints of ``m``
    (wrist bar 9 cm beyond the wrist along the forearm, ankle marker 2 cm beyond the ankle
    along the shank), each coordinate ± ``noise`` metres.
    Returns the markers and the true offsets (P, 3) in the calibration's segment frames."""
    from mocapflow.framework import quaternions as quat

    j = {n: m.canonical_positions((n,))[:, 0] for n in JOINTS}
    # pelvis markers fixed to the root: 5 cm above the hips, 5 cm before and behind
    up = quat.rotate(m.rotations[:, 0], np.array([0.0, 0.05, 0.0]))
    fw = quat.rotate(m.rotations[:, 0], np.array([0.0, 0.0, 0.05]))
    lab = {
        "LFWT": j["lhip"] + up + fw,
        "LBWT": j["lhip"] + up - fw,
        "RFWT": j["rhip"] + up + fw,
        "RBWT": j["rhip"] + up - fw,
    }
    v = unit(j["headtop"] - j["head"])
    side = unit(np.cross(v, [0.0, 0.0, 1.0]))
    front = np.cross(side, v)  # left x front = down the head bone
    for name, s, f in (("LFHD", 1, 1), ("RFHD", -1, 1), ("LBHD", 1, -1), ("RBHD", -1, -1)):
        lab[name] = j["headtop"] + 0.07 * s * side + 0.09 * f * front
    rest = rest_of(m)
    truth = {"root": tuple(root_from_hips(rest) + np.array([0.0, 0.0, 0.05]))}  # the markers' mean 5 cm above
    for s in "lr":
        u = unit(j[f"{s}wrist"] - j[f"{s}elbow"])
        p = unit(np.cross(u, [0.0, 1.0, 0.0]))
        bar = j[f"{s}wrist"] + 0.09 * u
        lab[f"{s.upper()}WRA"], lab[f"{s.upper()}WRB"] = bar + 0.03 * p, bar - 0.03 * p
        lab[f"{s.upper()}ELB"] = j[f"{s}elbow"]
        truth[f"{s}wrist"] = (0.0, 0.09, 0.0)  # x = WRA - WRB, y = towards the elbow
        ua = unit(j[f"{s}ankle"] - j[f"{s}knee"])
        lab[f"{s.upper()}ANK"] = j[f"{s}ankle"] + 0.02 * ua
        lab[f"{s.upper()}KNE"] = j[f"{s}knee"]
        lab[f"{s.upper()}SHN"] = (
            j[f"{s}knee"] + 0.5 * (j[f"{s}ankle"] - j[f"{s}knee"]) + 0.04 * unit(np.cross(ua, [1.0, 0, 0]))
        )
        truth[f"{s}ankle"] = (0.02, 0.0, 0.0)  # x = knee - ankle marker
    pos = np.stack(list(lab.values()), 1)
    pos = pos + np.random.default_rng(seed).uniform(-noise, noise, pos.shape)
    off = np.array([truth.get(p, (0.0, 0.0, 0.0)) for p in DEFAULT_MARKERS])
    return Markers(tuple(f"subj:{k}" for k in lab), pos, m.fps, name="take", metadata={"up_axis": "+y"}), off


def rest_of(m):  # type: ignore[no-untyped-def]
    from mocapflow.framework import Motion

    sk = m.skeleton
    still = Motion(sk, np.zeros((1, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (1, sk.n_joints, 1)), m.fps)
    return {n: still.canonical_positions((n,))[0, 0] for n in ("root", "lhip", "rhip")}


def lengths_of(m):  # type: ignore[no-untyped-def]
    from mocapflow.plugins.similarity.applications.reconstruct_prior import CANONICAL_PARENT

    pos = {n: m.canonical_positions((n,))[0, 0] for n in CANONICAL_PARENT}
    return {n: float(np.linalg.norm(pos[n] - pos[p])) for n, p in CANONICAL_PARENT.items() if p in pos}


def test_calibration_recovers_known_segment_offsets():
    m = periodic_motion(90, yaw_deg=30)
    mk, want = skin_markers(m)
    control, _, name, _, cal = calibrated_control(mk, "auto", lengths_of(m), None, root_from_hips(rest_of(m)))
    assert name == "vicon" and cal is not None
    assert list(cal.calibrated) == [True, False, True, True, True, True]
    assert np.abs(cal.offsets - want).max() < 0.006, (cal.offsets - want) * 100
    joints = m.canonical_positions(DEFAULT_MARKERS)
    err = np.linalg.norm(control - joints, axis=-1)
    assert err[:, [0, 2, 3, 4, 5]].max() < 0.015  # calibrated points on the joints (the root by its hips)
    raw, _, _, _, none = calibrated_control(mk, "auto", None)
    assert none is None and np.linalg.norm(raw - joints, axis=-1)[:, 2:4].min() > 0.07  # the bar 9 cm off
    rows = cal.rows()
    assert [r["point"] for r in rows] == list(DEFAULT_MARKERS) and abs(rows[2]["y_cm"] - 9.0) < 0.6
    assert "lwrist (" in cal.describe() and "head not calibrated" in cal.describe()


def test_calibration_take_and_window():
    m = periodic_motion(120, yaw_deg=-45)
    mk, want = skin_markers(m, seed=1)
    other, _ = skin_markers(periodic_motion(60, 0.4, yaw_deg=80), seed=2)
    _, _, _, _, cal = calibrated_control(mk, "auto", lengths_of(m), calibration_take=other)
    assert cal is not None and "calibration take" in cal.source and cal.frames == 60
    assert not cal.calibrated[0] and np.abs(cal.offsets - want)[2:].max() < 0.006  # no root_offset: root kept
    centres, _, _, _, _ = calibrated_control(mk, "vicon", None)
    first = calibrate(mk, centres, "vicon", DEFAULT_MARKERS, lengths_of(m), seconds=1.0)
    assert first.frames == 30 and np.abs(first.offsets - want)[2:].max() < 0.006


def test_occluded_segment_markers():
    """A calibration window that never sees a segment marker falls back to the whole take;
    frames that miss one get the offset vector interpolated (the marker mean still drives)."""
    m = periodic_motion(90, yaw_deg=10)
    mk, want = skin_markers(m)
    pos = mk.positions.copy()
    pos[:40, mk.labels.index("subj:LELB")] = np.nan
    occluded = Markers(mk.labels, pos, mk.fps, "take", mk.metadata)
    centres, _, _, _, _ = calibrated_control(occluded, "vicon", None)
    cal = calibrate(occluded, centres, "vicon", DEFAULT_MARKERS, lengths_of(m), seconds=1.0)
    assert "lwrist: the whole take" in cal.source and np.abs(cal.offsets - want)[2:].max() < 0.006
    pos = mk.positions.copy()
    pos[50:54, mk.labels.index("subj:LELB")] = np.nan  # a short gap: the vector interpolated
    control, _, _, _, _ = calibrated_control(
        Markers(mk.labels, pos, mk.fps, "take", mk.metadata), "vicon", lengths_of(m)
    )
    err = np.linalg.norm(control - m.canonical_positions(DEFAULT_MARKERS), axis=-1)
    assert np.isfinite(control).all() and err[:, 2].max() < 0.03


def test_root_needs_hip_motion():
    m = periodic_motion(60, amp=0.0)  # a frozen pose: the knee markers draw no sphere
    mk, _ = skin_markers(m)
    _, _, _, _, cal = calibrated_control(mk, "auto", lengths_of(m), None, root_from_hips(rest_of(m)))
    assert cal is not None and not cal.calibrated[0] and "root: no hip motion" in cal.source
    assert root_from_hips({"root": np.zeros(3)}) is None


def test_calibration_error_paths():
    m = periodic_motion(40)
    mk, _ = skin_markers(m)
    pos = mk.positions.copy()
    pos[:, mk.labels.index("subj:LELB")] = np.nan  # the elbow marker never seen
    with pytest.raises(DataError, match="calibrates lwrist"):
        calibrated_control(Markers(mk.labels, pos, mk.fps, "take", mk.metadata), "auto", lengths_of(m))
    with pytest.raises(DataError, match="need >= 10"):
        calibrated_control(mk.slice(0, 5), "auto", lengths_of(m))
    # a set without the segment markers keeps zero offsets, reported as not calibrated
    bare = mk.select([lb for lb in mk.labels if not lb.endswith(("ELB", "KNE", "SHN"))])
    _, _, _, _, cal = calibrated_control(bare, "auto", lengths_of(m))
    assert cal is not None and not cal.calibrated.any()
    with pytest.raises(DataError, match="lack the markers"):
        apply_offsets(bare, np.zeros((40, 6, 3)), "vicon", calibrated_control(mk, "auto", lengths_of(m))[4])
    with pytest.raises(DataError, match="calibration take"):
        calibrated_control(mk, "auto", lengths_of(m), calibration_take=mk.select(list(mk.labels[:4])))


def test_cli_reports_offsets_on_a_corpus_c3d(tmp_path, capsys):
    from mocapflow.framework.cli import main

    c3d = corpus_path("c3d", "cmu", "85_02.c3d")
    asf = corpus_path("cmu", "amc", "135", "135.asf")
    prior = corpus_path("cmu", "amc", "135", "135_04.amc")
    out = tmp_path / "out.bvh"
    argv = ["reconstruct", str(c3d), "--prior", str(prior), "--skeleton", str(asf), "-o", str(out), "-k", "16"]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "offsets from the first" in text and "lwrist (" in text and "lankle (" in text and out.is_file()
    assert main([*argv, "--calibration", "off"]) == 0
    assert "offsets: none" in capsys.readouterr().out
    assert main([*argv, "--calibration", str(tmp_path / "nope.c3d")]) == 2
    assert "--calibration" in capsys.readouterr().err
    amc = ["reconstruct", str(prior), "--prior", str(prior), "-o", str(out), "--calibration", str(c3d)]
    assert main(amc) == 2 and "for a marker take" in capsys.readouterr().err
