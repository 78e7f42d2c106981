"""``analyses.reconstruct``: full-body motion from sparse markers (Krüger et al. 2010, §5.2).

Chai & Hodgins (2005) with kNN searches in a feature space around the *synthesised* pose.
Per frame ``t``: predict from ``t-1, t-2`` (constant velocity); take the ``k`` nearest
database poses around the prediction; fit a local linear model (local PCA with the
neighbours' Gaussian prior, ``_local_model``); solve the small least-squares problem of
markers + prior + prediction; search again around the result (``iterations``). The first
frame starts from the database pose nearest its markers (24 headings); the first
``backward_frames`` frames are solved again backwards.

A pose is the vector of **root-normalised canonical joint positions** (metres, root at the
origin facing +z), not one skeleton's rotations: priors come from databases with other
skeletons (Table 3), the error is measured on positions, and markers are linear in them.
Heading and ground position come from the markers (2-D Procrustes alternated with the
solve). A synthesised pose has no clip around it, so its query vector is an affine map of
the pose fitted on the prior (``feature_fit_r2`` in the summary). The output Motion aims
the test clip's bones at the reconstructed positions (:func:`retarget.positions_to_motion`;
``fk_avg_cm`` is its error).

Tables: ``data``/``clips``/``skeletons`` (the reconstructions), ``errors`` (per clip and
joint: ``mean_cm, max_cm``), ``clip_errors`` (per clip: ``avg_cm``, ``max_cm``).
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import pyarrow as pa
from pydantic import Field

from mocapflow.framework import (
    Analysis,
    DataError,
    FeatureSet,
    Index,
    Motion,
    MotionDatabase,
    Params,
    StepContext,
    StepOutput,
)
from mocapflow.framework.datasets import Dataset
from mocapflow.framework.joints import CANONICAL_JOINTS
from mocapflow.framework.normalize import facing_angles, rotate_about_y

from .retarget import positions_to_motion

#: The paper's 6 markers: the 4 end effectors, the head and the root.
DEFAULT_MARKERS: tuple[str, ...] = ("root", "head", "lwrist", "rwrist", "lankle", "rankle")


def local_poses(positions: np.ndarray, joints: Sequence[str]) -> np.ndarray:
    """Root-normalised poses: root at the origin, heading (from the hips) turned to +z.

    positions : (T, P, 3) metres -> (T, P, 3) metres.
    """
    j = list(joints)
    centred = positions - positions[:, j.index("root")][:, None, :]
    return rotate_about_y(centred, -facing_angles(positions, j))


def synthetic_markers(
    motion: Motion,
    markers: Sequence[str] = DEFAULT_MARKERS,
    noise: float = 0.001,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Marker positions from a motion, each coordinate disturbed uniformly in ``±noise`` metres.

    Returns ndarray of shape (T, len(markers), 3), metres (the paper: ±1 mm).
    """
    rng = np.random.default_rng(0) if rng is None else rng
    pos = motion.canonical_positions(tuple(markers))
    if np.isnan(pos).any():
        missing = [m for m, i in zip(markers, motion.skeleton.canonical_indices(tuple(markers)), strict=True) if i < 0]
        raise DataError(f"motion {motion.name!r} lacks marker joints {missing}")
    return pos + rng.uniform(-noise, noise, pos.shape)


@dataclass
class PosePrior:
    """The prior database as the reconstruction sees it.

    Attributes
    ----------
    joints : tuple of str, P canonical joints of the pose vector
    poses : ndarray of float32, shape (N, P*3), root-normalised positions, metres
    features : ndarray of float32, shape (N, d), the kNN feature rows
    index : Index, built on ``features``
    feature_map : ndarray of shape (P*3 + 1, d), affine map pose -> query features
    feature_fit_r2 : float, coefficient of determination of that map on the database
    """

    joints: tuple[str, ...]
    poses: np.ndarray
    features: np.ndarray
    index: Index
    feature_map: np.ndarray
    feature_fit_r2: float

    @classmethod
    def build(cls, poses: np.ndarray, features: np.ndarray, index: Index, joints: Sequence[str]) -> PosePrior:
        """Fit the query map and build ``index`` on ``features`` (rows aligned with ``poses``)."""
        poses = np.ascontiguousarray(poses, np.float32).reshape(len(poses), -1)
        features = np.ascontiguousarray(features, np.float32)
        if len(poses) != len(features) or len(poses) < 2:
            raise DataError(f"prior: {len(poses)} poses and {len(features)} feature rows (need equal, >= 2)")
        if not (np.isfinite(poses).all() and np.isfinite(features).all()):
            raise DataError("prior: poses or features contain NaN (a prior clip lacks a pose joint?)")
        x = np.concatenate([poses, np.ones((len(poses), 1), np.float32)], 1).astype(np.float64)
        f = features.astype(np.float64)
        gram = x.T @ x
        gram[np.diag_indices_from(gram)] += 1e-9 * np.trace(gram) / len(gram)  # ridge: poses are rank-deficient
        fmap = np.linalg.solve(gram, x.T @ f)
        resid = ((x @ fmap - f) ** 2).sum()
        total = ((f - f.mean(0)) ** 2).sum()
        r2 = float(1.0 - resid / total) if total > 0 else 1.0
        index.build(features)
        return cls(tuple(joints), poses, features, index, fmap, r2)

    def query_features(self, pose: np.ndarray) -> np.ndarray:
        """Query vector (1, d) float32 of one pose (P*3,)."""
        return (pose @ self.feature_map[:-1] + self.feature_map[-1]).astype(np.float32)[None, :]


def _yaw_align(model: np.ndarray, observed: np.ndarray) -> float:
    """Yaw (radians) rotating ``model (M,3)`` onto ``observed (M,3)`` best in the ground plane."""
    s = np.sum(observed[:, 0] * model[:, 2] - observed[:, 2] * model[:, 0])
    c = np.sum(observed[:, 0] * model[:, 0] + observed[:, 2] * model[:, 2])
    return float(np.arctan2(s, c))


class ReconstructParams(Params):
    features: str = Field("end_effectors", description="features component of the kNN search")
    feature_params: dict = Field(default_factory=dict, description="parameters of that feature set")
    k: int = Field(64, ge=2, description="neighbours of the local linear model")
    leave_out: Literal["clip", "subject", "none"] = Field(
        "clip", description="prior clips withheld for each test clip: the same clip (by name), its subject, or none"
    )


@dataclass(frozen=True)
class ReconstructModel:
    """The reconstruction's fixed model (the paper's set-up; measured, docs/knn.md).

    ``markers``: canonical marker joints (root needed; the paper's 6); ``noise``: uniform
    marker disturbance, metres (paper: 1 mm), drawn with ``seed``; ``marker_sigma``: marker
    misfit scale, metres (model error dominates the 1 mm noise); ``smooth_sigma``: allowed
    deviation from the constant-velocity prediction, metres; ``iterations``: searches per
    frame (the 2nd around the synthesised pose); ``backward_frames``: first frames solved
    again backwards (they lack a past). The kNN index is ``indexes.kdtree`` on one thread
    (one query per frame: threads only add wake-up latency).
    """

    markers: tuple[str, ...] = DEFAULT_MARKERS
    noise: float = 0.001
    marker_sigma: float = 0.005
    smooth_sigma: float = 0.02
    iterations: int = 2
    backward_frames: int = 10
    seed: int = 0


MODEL = ReconstructModel()


def prior_index() -> Index:
    """The kNN index of a prior database: an exact kd-tree, one thread."""
    from ..knn.kdtree import KDTreeIndex

    return KDTreeIndex(workers=1)


def _local_model(nb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean (D,), centred neighbours X (K, D) and Gram matrix X X^T (K, K) of poses ``nb``.

    The local linear model keeps every principal component of the K neighbours with the
    Gaussian prior of their sample covariance C = X^T X / (K-1). Writing the pose as
    ``y = mu + X^T a`` turns that prior into ``(K-1) |a|^2`` (``X C^+ X^T = (K-1) U U^T``),
    so the MAP pose is one K x K solve and needs no eigen-decomposition -- which matters:
    LAPACK's threaded SVD costs 20-40 ms per frame on a loaded 2-core machine.
    """
    mu = nb.mean(0)
    x = nb - mu
    return mu, x, x @ x.T


def reconstruct_positions(
    markers: np.ndarray, prior: PosePrior, params: ReconstructParams | None = None, model: ReconstructModel = MODEL
) -> tuple[np.ndarray, np.ndarray]:
    """Reconstruct full poses from marker trajectories.

    Parameters
    ----------
    markers : ndarray of shape (T, M, 3), metres
        World positions of ``model.markers`` (which must include ``root``).
    prior : PosePrior
    params : ReconstructParams
    model : ReconstructModel

    Returns
    -------
    positions : ndarray of shape (T, P, 3), metres
        World positions of ``prior.joints``.
    heading : ndarray of shape (T,), radians
    """
    p = params or ReconstructParams()
    mk = model.markers
    markers = np.asarray(markers, np.float64)
    joints = list(prior.joints)
    if "root" not in mk or any(m not in joints for m in mk):
        raise DataError(f"markers {list(mk)} must include 'root' and lie in the pose joints {joints}")
    if markers.ndim != 3 or markers.shape[1:] != (len(mk), 3):
        raise DataError(f"markers must be (T, {len(mk)}, 3), got {markers.shape}")
    t_len, n_j = len(markers), len(joints)
    sel = np.array([[3 * joints.index(m) + a for a in range(3)] for m in mk]).ravel()
    root = markers[:, list(mk).index("root")]
    rel = markers - root[:, None, :]
    out = np.zeros((t_len, n_j * 3))
    heading = np.zeros(t_len)
    if t_len == 0:
        return out.reshape(0, n_j, 3), heading
    theta, guess = _initial_pose(rel[0], prior.poses, sel)
    # the first frame starts from a database pose and has no temporal context: search more often
    out[0], heading[0] = _solve_frame(rel[0], guess, theta, None, prior, sel, p.k, model, max(model.iterations, 5))
    for t in range(1, t_len):
        pred = 2 * out[t - 1] - out[t - 2] if t >= 2 else out[t - 1]
        out[t], heading[t] = _solve_frame(rel[t], pred, heading[t - 1], pred, prior, sel, p.k, model, model.iterations)
    # then a short backward pass: the first frames again, predicted from the later ones
    for t in range(min(model.backward_frames, t_len - 2) - 1, -1, -1):
        pred = 2 * out[t + 1] - out[t + 2]
        out[t], heading[t] = _solve_frame(rel[t], pred, heading[t + 1], pred, prior, sel, p.k, model, model.iterations)
    world = rotate_about_y(out.reshape(t_len, n_j, 3), heading) + root[:, None, :]
    return world, heading


def _solve_frame(
    rel: np.ndarray,
    guess: np.ndarray,
    theta: float,
    pred: np.ndarray | None,
    prior: PosePrior,
    sel: np.ndarray,
    k: int,
    model: ReconstructModel,
    iterations: int,
) -> tuple[np.ndarray, float]:
    """One frame: kNN around ``guess``, local model, MAP pose and heading (see module doc).

    rel : (M, 3) markers relative to the root marker; guess, pred : (D,) local poses;
    returns the pose (D,) and heading (radians).
    """
    w_m, w_s = 1.0 / model.marker_sigma**2, 1.0 / model.smooth_sigma**2
    k = min(k, len(prior.poses))
    for _ in range(iterations):
        _, ids = prior.index.query(prior.query_features(guess), k)
        nb = prior.poses[ids[0][ids[0] >= 0]].astype(np.float64)
        mu, x, gram = _local_model(nb)
        xs = x[:, sel]
        lhs = w_m * xs @ xs.T + max(len(nb) - 1, 1) * np.eye(len(nb))
        if pred is not None:
            lhs += w_s * gram
        for _ in range(2):  # alternate pose and heading
            obs = rotate_about_y(rel[None], np.array([-theta]))[0].ravel()
            rhs = w_m * xs @ (obs - mu[sel])
            if pred is not None:
                rhs += w_s * x @ (pred - mu)
            guess = mu + x.T @ np.linalg.solve(lhs, rhs)
            theta = _yaw_align(guess[sel].reshape(-1, 3), rel)
    return guess, theta


def _initial_pose(rel: np.ndarray, poses: np.ndarray, sel: np.ndarray, n_yaw: int = 24) -> tuple[float, np.ndarray]:
    """Heading and nearest database pose for the first frame: markers (M,3) relative to the
    root are compared with every database pose's marker joints under ``n_yaw`` headings."""
    yaws = np.linspace(0, 2 * np.pi, n_yaw, endpoint=False)
    cand = rotate_about_y(np.broadcast_to(rel, (n_yaw,) + rel.shape), -yaws).reshape(n_yaw, -1)
    db = poses[:, sel].astype(np.float64)
    d2 = (db * db).sum(1)[:, None] - 2 * db @ cand.T + (cand * cand).sum(1)[None, :]
    row, col = np.unravel_index(int(np.argmin(d2)), d2.shape)
    pose = poses[row].astype(np.float64)
    return _yaw_align(pose[sel].reshape(-1, 3), rel), pose


def joint_errors(recon: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Per-joint mean and max error (P,), overall average and max per-frame mean, all in cm.

    recon, truth : (T, P, 3) metres; NaN joints of ``truth`` are ignored.
    """
    err = np.linalg.norm(recon - truth, axis=-1) * 100.0
    ok = ~np.isnan(err)
    with np.errstate(invalid="ignore"):
        per_joint_mean = np.nanmean(np.where(ok, err, np.nan), 0)
        per_joint_max = np.nanmax(np.where(ok, err, np.nan), 0)
        frame_mean = np.nanmean(np.where(ok, err, np.nan), 1)
    return per_joint_mean, per_joint_max, float(np.nanmean(frame_mean)), float(np.nanmax(frame_mean))


class PriorDatabase:
    """Poses and feature rows of candidate prior clips, computed once, so that priors
    leaving out different clips (Tables 3 and 4) only concatenate and rebuild the index.

    Parameters
    ----------
    db : MotionDatabase
    feature_set : FeatureSet
        Fitted if it needs fitting; features are computed clip by clip.
    joints : sequence of str
        Pose joints; joints some clip lacks are dropped.
    """

    def __init__(self, db: MotionDatabase, feature_set: FeatureSet, joints: Sequence[str] = CANONICAL_JOINTS) -> None:
        present = [j for j in joints if all(j in m.skeleton.canonical for m in db.motions)]
        self.joints = tuple(present)
        self.names = [m.name for m in db.motions]
        self.subjects = [str(m.metadata.get("subject", "")) for m in db.motions]
        self.poses = [
            local_poses(m.canonical_positions(self.joints), self.joints).reshape(m.n_frames, -1).astype(np.float32)
            for m in db.motions
        ]
        self.features = [np.asarray(feature_set.transform(m), np.float32) for m in db.motions]

    @property
    def n_frames(self) -> np.ndarray:
        return np.array([len(p) for p in self.poses])

    def withheld(self, motion: Motion, leave_out: str) -> np.ndarray:
        """Mask of clips to leave out for a test clip: same name, same subject, or none."""
        if leave_out == "subject":
            subj = str(motion.metadata.get("subject", ""))
            return np.array([s == subj for s in self.subjects])
        if leave_out == "clip":
            return np.array([n == motion.name for n in self.names])
        return np.zeros(len(self.names), bool)

    def prior(self, keep: np.ndarray, index: Index) -> PosePrior:
        """A :class:`PosePrior` of the clips where ``keep`` is true (``index`` is built)."""
        rows = np.flatnonzero(keep)
        if len(rows) == 0:
            raise DataError("prior database is empty after leaving out the test clips")
        return PosePrior.build(
            np.concatenate([self.poses[i] for i in rows]),
            np.concatenate([self.features[i] for i in rows]),
            index,
            self.joints,
        )


def reconstruct_motion(
    motion: Motion, prior: PosePrior, params: ReconstructParams | None = None, model: ReconstructModel = MODEL
) -> tuple[Motion, dict]:
    """Reconstruct one clip from its synthetic markers; the result and its errors.

    Returns the reconstructed Motion (test clip's skeleton, ``<name>_recon``) and a dict:
    ``joints``, ``mean_cm``/``max_cm`` per joint, ``avg_cm``, ``max_cm``, ``fk_avg_cm``,
    ``seconds`` (reconstruction time, excluding the prior).
    """
    p = params or ReconstructParams()
    markers = synthetic_markers(motion, model.markers, model.noise, np.random.default_rng(model.seed))
    t0 = time.perf_counter()
    world, _ = reconstruct_positions(markers, prior, p, model)
    seconds = time.perf_counter() - t0
    truth = motion.canonical_positions(prior.joints)
    mean, mx, avg, worst = joint_errors(world, truth)
    out = positions_to_motion(
        motion.skeleton,
        world,
        prior.joints,
        motion.fps,
        name=f"{motion.name}_recon",
        metadata={**motion.metadata, "reconstructed_from": motion.name},
    )
    _, _, fk_avg, _ = joint_errors(out.canonical_positions(prior.joints), truth)
    return out, {
        "joints": prior.joints,
        "mean_cm": mean,
        "max_cm": mx,
        "avg_cm": avg,
        "max_frame_cm": worst,
        "fk_avg_cm": fk_avg,
        "seconds": seconds,
    }


ERRORS = pa.schema(
    [
        ("clip_id", pa.int32()),
        ("name", pa.string()),
        ("joint", pa.string()),
        ("mean_cm", pa.float64()),
        ("max_cm", pa.float64()),
    ]
)
CLIP_ERRORS = pa.schema(
    [
        ("clip_id", pa.int32()),
        ("name", pa.string()),
        ("n_frames", pa.int32()),
        ("prior_frames", pa.int64()),
        ("avg_cm", pa.float64()),
        ("max_cm", pa.float64()),
        ("fk_avg_cm", pa.float64()),
        ("frames_per_s", pa.float64()),
    ]
)


class Reconstruct(Analysis):
    """Full-body motion from 6 sparse markers with kNN local linear pose priors (Krüger 2010 §5.2)."""

    name = "reconstruct"
    inputs: Mapping[str, bool] = {"prior": True, "test": True}
    Params = ReconstructParams

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        from mocapflow.framework.motion_tables import motions_to_tables

        p = self.params
        prior_db, test_db = inputs["prior"].motions(), inputs["test"].motions()
        fs = ctx.registries["features"].get(p.features)(p.feature_params)
        if fs.requires_fit:
            fs.fit(prior_db)
        store = PriorDatabase(prior_db, fs)
        motions, err_rows, clip_rows, cache = [], [], [], {}
        for cid, m in zip(
            test_db.clip_ids, ctx.progress(test_db.motions, total=test_db.n_clips, desc=ctx.step_id), strict=True
        ):
            keep = ~store.withheld(m, p.leave_out)
            key = keep.tobytes()
            if key not in cache:  # one index per distinct left-out set
                cache = {key: store.prior(keep, prior_index())}
            rec, e = reconstruct_motion(m, cache[key], p)
            motions.append(rec)
            err_rows += [
                {"clip_id": int(cid), "name": m.name, "joint": j, "mean_cm": float(a), "max_cm": float(b)}
                for j, a, b in zip(e["joints"], e["mean_cm"], e["max_cm"], strict=True)
                if np.isfinite(a)
            ]
            clip_rows.append(
                {
                    "clip_id": int(cid),
                    "name": m.name,
                    "n_frames": m.n_frames,
                    "prior_frames": int(store.n_frames[keep].sum()),
                    "avg_cm": e["avg_cm"],
                    "max_cm": e["max_frame_cm"],
                    "fk_avg_cm": e["fk_avg_cm"],
                    "frames_per_s": m.n_frames / max(e["seconds"], 1e-9),
                }
            )
        tables = motions_to_tables(motions, list(test_db.clip_ids))
        tables["errors"] = pa.Table.from_pylist(err_rows, schema=ERRORS)
        tables["clip_errors"] = pa.Table.from_pylist(clip_rows, schema=CLIP_ERRORS)
        frames = sum(r["n_frames"] for r in clip_rows)
        summary = {
            "clips": len(clip_rows),
            "frames": frames,
            "avg_cm": float(np.mean([r["avg_cm"] for r in clip_rows])) if clip_rows else None,
            "feature_fit_r2": float(next(iter(cache.values())).feature_fit_r2) if cache else None,
            "backend": f"features.{p.features} + indexes.kdtree",
        }
        return StepOutput(tables, summary)
