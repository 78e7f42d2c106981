"""Reconstruction from marker files as users have them: offsets calibrated per performer.

    python benchmarks/reconstruct_markers.py               # every check below
    python benchmarks/reconstruct_markers.py --no-hdm05    # skip the 49-s HDM05 take
    python benchmarks/reconstruct_markers.py --quick       # its first 10 s only

Prior: every take of ../shared/data (``benchmarks/reconstruct.py``'s cached store) but the
performer's subject. Checks:

* CMU 135_02 C3D on its subject's ASF against the take's own AMC. The two share the lab
  frame up to the axis convention: the yaw is fitted on the root's trajectory (pelvis marker
  mean vs AMC root: offset-free up to a constant), the frames correspond one to one (both
  5202 frames at 120 Hz; the best lag is printed), and the reconstruction is compared with
  the AMC rotated by that yaw, no shift (the ankle markers sit at the AMC ankles' height; the
  figure after the mean translation over all joints and frames, which would hide a body
  placed too high, is printed beside it). Errors per joint and mean: without calibration, with
  the self-calibration of the first ``--cal-seconds`` evaluated on the *rest* of the take,
  and the bound of offsets fitted to the AMC itself on the calibration window (not a
  calibration: it uses the truth), and the floor of six perfect points (the AMC's own control
  joints and heading).
* CMU 85_02 C3D (no AMC; reconstructed on 135.asf, not the performer's skeleton): offsets
  calibrated on the first and on the last ``--cal-seconds`` (at most half the take each;
  their difference: consistency)
  and the fit of the output's control joints to the calibrated control points.
* HDM05 bd C3D on HDM_bd.asf: median distance of the reconstructed knees from the knee
  markers, without and with calibration.
* The OpenSim TRC and the ezc3d Qualisys/Vicon samples through the CLI's code path (on 135.asf):
  the reconstruction or the clear error a user gets.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from corpus import DATA
from reconstruct import load_store, prior_files

from mocapflow.framework import DataError, Motion
from mocapflow.framework.markers import to_y_up
from mocapflow.plugins.formats.asf_amc import read_amc, read_asf
from mocapflow.plugins.formats.c3d import read_c3d
from mocapflow.plugins.similarity.applications.reconstruct import DEFAULT_MARKERS, PosePrior, reconstruct_positions
from mocapflow.plugins.similarity.applications.reconstruct_calibrate import (
    SEGMENTS,
    Calibration,
    apply_offsets,
    root_from_hips,
    segment_frames,
)
from mocapflow.plugins.similarity.applications.reconstruct_markers import (
    calibrated_control,
    control_from_motion,
    resolve_marker_set,
)
from mocapflow.plugins.similarity.applications.reconstruct_prior import bone_lengths
from mocapflow.plugins.similarity.applications.reconstruct_synthetic import joint_errors
from mocapflow.plugins.similarity.applications.retarget import positions_to_motion

CP = DEFAULT_MARKERS


def lengths_of(skeleton, joints):  # type: ignore[no-untyped-def]
    rest = Motion(skeleton, np.zeros((1, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (1, skeleton.n_joints, 1)), 30.0)
    return bone_lengths(rest.canonical_positions(joints), joints)


class Setup:
    def __init__(self, store, skeleton, subject: str) -> None:  # type: ignore[no-untyped-def]
        self.skeleton = skeleton
        self.lengths = lengths_of(skeleton, store.joints)
        keep = np.array([c["subject"] != subject for c in store.clips])
        self.prior = PosePrior.build(store, self.lengths, keep)
        self.by_joint = dict(zip(store.joints, self.lengths, strict=True))
        rest = Motion(skeleton, np.zeros((1, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (1, skeleton.n_joints, 1)), 30.0)
        hips = ("root", "lhip", "rhip")
        self.root_offset = root_from_hips(dict(zip(hips, rest.canonical_positions(hips)[0], strict=True)))

    def run(self, markers, cal=True, calibration_take=None, frames=slice(None)):  # type: ignore[no-untyped-def]
        control, heading, set_name, _, c = calibrated_control(
            markers, "auto", self.by_joint if cal else None, calibration_take, self.root_offset
        )
        t = time.perf_counter()
        world, _ = reconstruct_positions(control[frames], self.prior, root_heading=heading[frames])
        sec = time.perf_counter() - t
        out = positions_to_motion(self.skeleton, world, self.prior.joints, markers.fps)
        return out.canonical_positions(self.prior.joints), control[frames], c, sec, set_name


def yaw_matrix(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def cmu_135(store, args) -> None:  # type: ignore[no-untyped-def]
    c3d, amc = DATA / "c3d/cmu/135_02.c3d", DATA / "cmu/amc/135/135_02.amc"
    if not (c3d.is_file() and amc.is_file()):
        print("135_02: C3D or AMC absent, skipped")
        return
    mk, truth = read_c3d(c3d), read_amc(amc)
    su = Setup(store, read_asf(amc.parent / "135.asf"), "135")
    y_up = to_y_up(mk)
    _, mapping = resolve_marker_set(y_up, "vicon")
    root_mk = np.mean(y_up.select(list(mapping["root"])).positions, axis=1)
    root_amc = truth.canonical_positions(("root",))[:, 0]
    # frame correspondence and the lab frames: yaw of the root trajectories per lag
    best = None
    for lag in range(-6, 7):
        n = len(root_mk) - abs(lag)
        a, b = root_mk[max(lag, 0) : max(lag, 0) + n], root_amc[max(-lag, 0) : max(-lag, 0) + n]
        a0, b0 = a - a.mean(0), b - b.mean(0)
        yaw = np.arctan2(
            np.sum(b0[:, 0] * a0[:, 2] - b0[:, 2] * a0[:, 0]), np.sum(b0[:, 0] * a0[:, 0] + b0[:, 2] * a0[:, 2])
        )
        res = np.linalg.norm(a0 @ yaw_matrix(yaw).T - b0, axis=1).mean() * 100
        scale = np.linalg.norm(np.diff(b, axis=0), axis=1).sum() / np.linalg.norm(np.diff(a, axis=0), axis=1).sum()
        if best is None or res < best[1]:
            best = (lag, res, yaw, scale)
    lag, res, yaw, scale = best
    print(
        f"135_02: C3D {mk.n_frames} frames at {mk.fps:g} Hz (first frame {mk.metadata.get('first_frame')}), "
        f"AMC {truth.n_frames} at {truth.fps:g} Hz; root trajectories: best lag {lag} frames, yaw {np.degrees(yaw):.2f} deg, "
        f"path-length ratio {scale:.4f}, residual {res:.2f} cm"
    )
    rot = yaw_matrix(yaw)
    truth_j = truth.canonical_positions(su.prior.joints)
    truth_c = truth.canonical_positions(CP)
    cal_n = int(round(args.cal_seconds * mk.fps))
    rest = slice(cal_n, mk.n_frames)

    def report(label: str, recon: np.ndarray, control: np.ndarray, frames: slice) -> float:
        x = recon @ rot.T
        y = truth_j[frames]
        per, _, avg, worst = joint_errors(x, y)
        shift = (y - x).reshape(-1, 3).mean(0)
        shifted = joint_errors(x + shift, y)[2]
        ctrl = np.linalg.norm(control @ rot.T - truth_c[frames], axis=-1).mean(0) * 100
        print(
            f"  {label}: {avg:.2f} cm per joint (worst frame {worst:.1f}; {shifted:.2f} after the mean shift "
            f"{np.round(shift * 100, 1).tolist()} cm); control points off the joints: "
            + ", ".join(f"{p} {v:.1f}" for p, v in zip(CP, ctrl, strict=True))
        )
        print("    per joint: " + ", ".join(f"{j} {v:.1f}" for j, v in zip(su.prior.joints, per, strict=True)))
        return avg

    recon, control, _, sec, _ = su.run(mk, cal=False)
    report(f"no calibration, all {mk.n_frames} frames ({mk.n_frames / sec:.0f} frames/s)", recon, control, slice(None))
    recon, control, _, _, _ = su.run(mk, cal=False, frames=rest)
    report(f"no calibration, frames after {args.cal_seconds:g} s", recon, control, rest)
    recon, control, c, _, _ = su.run(mk, cal=True, frames=rest)
    print("  " + c.describe())
    report(f"self-calibrated on the first {args.cal_seconds:g} s, frames after", recon, control, rest)
    recon, control, c, _, _ = su.run(mk, cal=True)
    report("self-calibrated, all frames (training figure: calibration frames included)", recon, control, slice(None))
    # the bound: offsets fitted to the AMC on the calibration window (uses the truth)
    keys = {lb.rsplit(":", 1)[-1].lower(): i for i, lb in enumerate(y_up.labels)}
    centres = np.stack([np.mean(y_up.select(list(mapping[p])).positions, axis=1) for p in CP], 1)
    want = truth_c @ rot
    off = np.zeros((len(CP), 3))
    ok = np.zeros(len(CP), bool)
    for i, p in enumerate(CP):
        if p in SEGMENTS["vicon"]:
            r = segment_frames(y_up.positions[:cal_n], keys, SEGMENTS["vicon"][p], centres[:cal_n, i])
            off[i], ok[i] = np.nanmean(np.einsum("tij,ti->tj", r, want[:cal_n, i] - centres[:cal_n, i]), 0), True
    oracle = Calibration(CP, off, ok, cal_n, "the AMC")
    control_o = apply_offsets(y_up, centres, "vicon", oracle)
    _, heading, _, _, _ = calibrated_control(mk, "vicon", None)
    world, _ = reconstruct_positions(control_o[rest], su.prior, root_heading=heading[rest])
    out = positions_to_motion(su.skeleton, world, su.prior.joints, mk.fps).canonical_positions(su.prior.joints)
    print("  " + oracle.describe())
    report("bound: offsets fitted to the AMC on the first seconds, frames after", out, control_o[rest], rest)
    want_c, want_h = control_from_motion(truth)  # the floor: the AMC's own joints as control points
    world, _ = reconstruct_positions(want_c[rest], su.prior, root_heading=want_h[rest])
    out = positions_to_motion(su.skeleton, world, su.prior.joints, mk.fps).canonical_positions(su.prior.joints)
    report("floor: the AMC's own control joints and heading, frames after", out @ rot, want_c[rest] @ rot, rest)


def cmu_85(store, args) -> None:  # type: ignore[no-untyped-def]
    c3d = DATA / "c3d/cmu/85_02.c3d"
    if not c3d.is_file():
        return
    mk = read_c3d(c3d)
    su = Setup(store, read_asf(DATA / "cmu/amc/135/135.asf"), "85")
    n = min(int(round(args.cal_seconds * mk.fps)), mk.n_frames // 2)
    _, _, _, _, first = calibrated_control(mk.slice(0, n), "auto", su.by_joint, None, su.root_offset)
    tail = mk.slice(max(0, mk.n_frames - n), mk.n_frames)
    _, _, _, _, last = calibrated_control(tail, "auto", su.by_joint, None, su.root_offset)
    diff = np.linalg.norm(first.offsets - last.offsets, axis=1) * 100
    both = first.calibrated & last.calibrated
    print(f"85_02 ({mk.n_frames} frames at {mk.fps:g} Hz, on 135.asf): {first.describe()}")
    print(f"  last {n} frames: {last.describe()}")
    print(
        "  first vs last offsets differ by "
        + ", ".join(f"{p} {v:.1f}" for p, v, ok in zip(CP, diff, both, strict=True) if ok)
        + " cm (points calibrated in both)"
    )
    for cal in (False, True):
        recon, control, _, sec, _ = su.run(mk, cal=cal)
        idx = [su.prior.joints.index(p) for p in CP]
        fit = np.linalg.norm(recon[:, idx] - control, axis=-1) * 100
        print(
            f"  {'calibrated' if cal else 'uncalibrated'}: output control joints {fit.mean():.1f} cm mean, "
            f"{fit.max():.1f} max off the control points; {mk.n_frames / sec:.0f} frames/s"
        )


def hdm05(store, args) -> None:  # type: ignore[no-untyped-def]
    c3d = DATA / "c3d/hdm05/HDM_bd_05-01_01_120.c3d"
    asf = DATA / "hdm05/amc/bd/HDM_bd.asf"
    if not (c3d.is_file() and asf.is_file()):
        return
    mk = read_c3d(c3d)
    if args.max_frames:
        mk = mk.slice(0, min(mk.n_frames, args.max_frames))
    su = Setup(store, read_asf(asf), "bd")
    y_up = to_y_up(mk)
    keys = {lb.rsplit(":", 1)[-1].lower(): i for i, lb in enumerate(y_up.labels)}
    knees = y_up.positions[:, [keys["lkne"], keys["rkne"]]]
    idx = [su.prior.joints.index(j) for j in ("lknee", "rknee")]
    for cal in (False, True):
        recon, _, c, sec, _ = su.run(mk, cal=cal)
        d = np.linalg.norm(recon[:, idx] - knees, axis=-1) * 100
        print(
            f"HDM05 bd 05-01_01 ({mk.n_frames} frames, {'calibrated' if cal else 'uncalibrated'}): reconstructed knees "
            f"median {np.nanmedian(d):.1f} cm (left {np.nanmedian(d[:, 0]):.1f}, right {np.nanmedian(d[:, 1]):.1f}; "
            f"90th pct {np.nanpercentile(d, 90):.1f}) from the knee markers; {mk.n_frames / sec:.0f} frames/s"
        )
        if c is not None:
            print("  " + c.describe())


def samples(store) -> None:  # type: ignore[no-untyped-def]
    from mocapflow.plugins.formats.trc import read_trc

    su = Setup(store, read_asf(DATA / "cmu/amc/135/135.asf"), "")
    files = sorted((DATA / "trc/opensim").glob("*.trc")) + sorted((DATA / "c3d/ezc3d_samples").glob("*.c3d"))
    for f in files:
        try:
            mk = read_trc(f) if f.suffix == ".trc" else read_c3d(f)
            recon, control, c, sec, set_name = su.run(mk)
            idx = [su.prior.joints.index(p) for p in CP]
            fit = np.linalg.norm(recon[:, idx] - control, axis=-1).mean() * 100
            print(f"{f.name}: set {set_name}, {mk.n_frames} frames, fit {fit:.1f} cm; {c.describe()}")
        except DataError as e:
            print(f"{f.name}: refused: {e}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cal-seconds", type=float, default=10.0, help="calibration window (default 10 s)")
    ap.add_argument("--quick", action="store_true", help="HDM05: the first 1200 frames only")
    ap.add_argument("--no-hdm05", action="store_true")
    ap.add_argument("--max-frames", type=int, default=0, help="HDM05: first frames only (0: all)")
    args = ap.parse_args()
    if args.quick:
        args.max_frames = args.max_frames or 1200
    if not (DATA / "c3d").is_dir():
        # the marker takes (C3D/TRC) are not bundled with the repository
        msg = f"corpus absent at {DATA} (set MOCAPFLOW_DATA): no marker take to measure"
        if args.quick:
            print(msg)
            return
        raise SystemExit(msg)
    store = load_store(prior_files(DATA))
    cmu_135(store, args)
    cmu_85(store, args)
    if not args.no_hdm05:
        hdm05(store, args)
    samples(store)


if __name__ == "__main__":
    main()
