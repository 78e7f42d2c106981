"""``analyses.reconstruct``: full-body motion from sparse markers (Krüger et al. 2010, §5.2).

Chai & Hodgins (2005) local linear models on a kNN prior. The prior
(:mod:`.reconstruct_prior`) holds every take as bone directions; for the performer being
reconstructed it is **retargeted to the performer's bone lengths** (the output skeleton's),
so a prior pose and the performer's markers agree in proportions. A pose is the vector of
root-normalised canonical joint positions (metres, root at the origin facing +z).

Per frame ``t``: the query is the control signal itself, as in the paper: the 5 non-root
markers relative to the root marker in the root's heading frame (F_E^15). The ``k``
nearest prior poses give a local linear model (local PCA with the neighbours' Gaussian
prior, :func:`_local_model`); the MAP pose of markers + prior + smoothness (deviation from
the constant-velocity prediction from ``t-1, t-2``) is one ``k x k`` solve. The root's
heading is part of the control signal when given (a pelvis marker cluster: the paper's
features are normalised by root position and orientation); otherwise it is alternated
with the solve (2-D Procrustes on the markers) and the search repeated under the new
heading (``iterations``). The result is put on the performer's bone lengths (directions
kept) and each limb's end on its marker by two-bone IK (:func:`limb_ik`), which bounds
every joint to its chain from the root marker. The first frame starts from the prior pose
nearest its markers; the first ``backward_frames`` frames are solved again backwards.
Then ``smooth_passes`` passes solve every frame again with the prediction from both its
neighbours of the pass before (a forward-backward smoother), and the side of every knee
and elbow is chosen over the whole take (:func:`consistent_sides`): dynamic programming
over positions of the middle joint on its IK circle, against the prior's configurations
of that limb (joint limits), the solve's choice and the joint's step between frames.

:func:`reconstruct` also gives a confidence per frame (:class:`Reconstruction`: how far
the query lies from the prior, the marker misfit, markers out of reach, joint limits);
:func:`reconstruct_positions` is its positions and heading.

The output Motion aims the performer's bones at the reconstructed positions
(:func:`retarget.positions_to_motion`; ``fk_avg_cm`` is its error).

Tables: ``data``/``clips``/``skeletons`` (the reconstructions), ``errors`` (per clip and
joint: ``mean_cm, max_cm``), ``clip_errors`` (per clip: ``avg_cm``, ``max_cm``,
``max_joint_cm``, ``confidence_mean``/``_min``, ``low_confidence_share``), ``confidence``
(per frame: ``clip_id, frame, confidence, novelty, misfit_cm, reach_cm, limit``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal, cast

import numpy as np
from pydantic import Field

from mocapflow.framework import (
    DataError,
    Index,
    Params,
)
from mocapflow.framework.normalize import rotate_about_y

from .reconstruct_prior import PriorStore, bone_parents, chain_matrix, prior_index
from .reconstruct_sides import consistent_sides

#: The paper's 6 markers: the 4 end effectors, the head and the root.
DEFAULT_MARKERS: tuple[str, ...] = ("root", "head", "lwrist", "rwrist", "lankle", "rankle")


def _yaw_align(model: np.ndarray, observed: np.ndarray) -> float:
    """Yaw (radians) rotating ``model (M,3)`` onto ``observed (M,3)`` best in the ground plane."""
    s = np.sum(observed[:, 0] * model[:, 2] - observed[:, 2] * model[:, 0])
    c = np.sum(observed[:, 0] * model[:, 0] + observed[:, 2] * model[:, 2])
    return float(np.arctan2(s, c))


class ReconstructParams(Params):
    k: int = Field(128, ge=2, description="neighbours of the local linear model")
    leave_out: Literal["clip", "subject", "none"] = Field(
        "clip", description="prior takes withheld for each test clip: the same clip (by name), its subject, or none"
    )


@dataclass(frozen=True)
class ReconstructModel:
    """The reconstruction's fixed model (measured: docs/knn.md, "How the default was chosen").

    ``markers``: canonical marker joints (root needed; the paper's 6); ``noise``: uniform
    marker disturbance of synthetic markers, metres (paper: 1 mm), drawn with ``seed``;
    ``marker_sigma``: marker misfit scale, metres; ``smooth_sigma``: allowed deviation from
    the constant-velocity prediction, metres; ``iterations``: searches per frame (estimated
    heading);
    ``backward_frames``: first frames solved again backwards (they lack a past);
    ``project``: put the solved pose on the performer's bone lengths, limbs on their
    markers; ``root_heading``: the root marker carries its heading (synthetic: from the
    hips, ±``noise``), else it is estimated from the markers. The kNN index is
    ``indexes.kdtree`` on one thread (one query per search).

    Side of the knees and elbows (:func:`consistent_sides`; 0 ``swivel_states``: off):
    ``swivel_states`` candidate positions of the middle joint on its IK circle, chosen
    per limb over the take by dynamic programming; costs: the limb's distance to the
    nearest prior configuration (joint limits), scale ``limit_sigma`` (unit-vector
    distance); the distance from the solve's middle joint, ``swivel_sigma`` metres; the
    middle joint's step between frames, ``swivel_step`` metres per prior frame.
    ``smooth_passes``: passes after the first, each predicting every frame from both its
    neighbours of the pass before (a forward-backward smoother); an estimated heading is
    averaged over ``±heading_window`` seconds before them and held (one search per frame).
    Confidence (:class:`Reconstruction`): marker misfit scale ``confidence_misfit`` and
    out-of-reach scale ``confidence_reach``, metres.
    """

    markers: tuple[str, ...] = DEFAULT_MARKERS
    noise: float = 0.001
    marker_sigma: float = 0.02
    smooth_sigma: float = 0.05
    iterations: int = 2
    backward_frames: int = 10
    project: bool = True
    root_heading: bool = True
    seed: int = 0
    swivel_states: int = 12
    limit_sigma: float = 0.1
    swivel_sigma: float = 0.1
    swivel_step: float = 0.05
    smooth_passes: int = 1
    heading_window: float = 0.25
    confidence_misfit: float = 0.04
    confidence_reach: float = 0.02


MODEL = ReconstructModel()


@dataclass
class PosePrior:
    """The prior as one performer's reconstruction sees it (retargeted to ``lengths``).

    Attributes
    ----------
    joints : tuple of str, P canonical joints of the pose vector
    lengths : ndarray (P,), the performer's bone lengths, metres
    fps : float, the prior's frame rate
    poses : ndarray of float32, shape (N, P*3), root-normalised positions, metres
    features : ndarray of float32, shape (N, d), the kNN rows: the non-root markers
    index : Index, built on ``features``
    typical : ndarray (KMAX,), the prior's typical mean distance of a query to its first
        ``k`` neighbours (entry ``k - 1``): the median over sampled prior rows, each
        searched among the other subjects' rows (:func:`typical_distances`)
    limits : dict, the joint-limit indexes of the limbs (built on first use)
    """

    joints: tuple[str, ...]
    lengths: np.ndarray
    fps: float
    markers: tuple[str, ...]
    poses: np.ndarray
    features: np.ndarray
    index: Index
    typical: np.ndarray = field(default_factory=lambda: np.ones(TYPICAL_K))
    limits: dict[tuple[int, int, int], Index] = field(default_factory=dict)

    @classmethod
    def build(
        cls,
        store: PriorStore,
        lengths: np.ndarray,
        keep: np.ndarray | None = None,
        index: Index | None = None,
        model: ReconstructModel = MODEL,
    ) -> PosePrior:
        """The takes of ``store`` where ``keep`` (C,) is true, on bone ``lengths`` (P,)."""
        joints = list(store.joints)
        if "root" not in model.markers or any(m not in joints for m in model.markers):
            raise DataError(f"markers {list(model.markers)} must include 'root' and lie in the pose joints {joints}")
        rows = store.rows(np.ones(len(store.clips), bool) if keep is None else np.asarray(keep, bool))
        if len(rows) < 2:
            raise DataError(f"prior: {len(rows)} frames left after leaving out the test takes (need >= 2)")
        lengths = np.asarray(lengths, np.float64)
        if lengths.shape != (len(joints),) or not np.isfinite(lengths).all():
            raise DataError(f"bone lengths must be {len(joints)} finite numbers, got shape {lengths.shape}")
        poses = store.retarget(lengths, rows)
        cols = [joints.index(m) for m in model.markers if m != "root"]
        feat = poses[:, cols].reshape(len(rows), -1)
        features = np.ascontiguousarray(feat, np.float32)
        index = index or prior_index()
        index.build(features)
        subject = np.array([c["subject"] or c["name"] for c in store.clips])
        owner = np.repeat(np.arange(len(store.clips)), np.diff(store.clip_rows))[rows]
        typical = typical_distances(features, np.unique(subject, return_inverse=True)[1][owner])
        return cls(
            store.joints, lengths, store.fps, model.markers, poses.reshape(len(rows), -1), features, index, typical
        )


#: Most neighbour ids (frames x k) one reconstruction keeps for its later passes (~100 MB).
NEIGHBOUR_CACHE = 8_000_000

#: Neighbour counts covered by :attr:`PosePrior.typical`.
TYPICAL_K = 256


def typical_distances(features: np.ndarray, groups: np.ndarray, n_sample: int = 128) -> np.ndarray:
    """Median over ``n_sample`` evenly spaced rows of ``features`` (N, d) of the mean
    distance to their first ``k`` nearest rows of *other* ``groups`` (N,), for every ``k``
    up to :data:`TYPICAL_K` (brute force; beyond the fewest rows of other groups a sampled
    row has: the last value); ones where a sampled row has no other group."""
    n = len(features)
    sample = np.unique(np.linspace(0, n - 1, min(n_sample, n)).astype(np.int64))
    f = np.asarray(features, np.float64)
    q = f[sample]
    d2 = (q * q).sum(1)[:, None] - 2 * q @ f.T + (f * f).sum(1)[None, :]
    other = groups[sample][:, None] != groups[None, :]
    d2[~other] = np.inf
    kmax = min(TYPICAL_K, int(other.sum(1).min()))
    out = np.ones(TYPICAL_K)
    if kmax > 0:
        near = np.sqrt(np.maximum(np.sort(np.partition(d2, kmax - 1, axis=1)[:, :kmax], axis=1), 0.0))
        prof = np.median(np.cumsum(near, 1) / np.arange(1, kmax + 1), 0)
        out[:kmax] = np.maximum(prof, 1e-9)
        out[kmax:] = out[kmax - 1]
    return out


def _local_model(nb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean (D,), centred neighbours X (K, D) and Gram matrix X X^T (K, K) of poses ``nb``.

    The local linear model keeps every principal component of the K neighbours with the
    Gaussian prior of their sample covariance C = X^T X / (K-1). Writing the pose as
    ``y = mu + X^T a`` turns that prior into ``(K-1) |a|^2`` (``X C^+ X^T = (K-1) U U^T``),
    so the MAP pose is one K x K solve and needs no eigen-decomposition.
    """
    mu = nb.mean(0)
    x = nb - mu
    return mu, x, x @ x.T


@dataclass
class _Frames:
    """Per-take constants of one reconstruction: marker columns, the bone projection."""

    sel: np.ndarray
    nonroot: np.ndarray
    parents: np.ndarray
    chain: np.ndarray
    lengths: np.ndarray
    limbs: list[tuple[int, int, int, int, np.ndarray]]


#: Two-bone chains (base, middle, end) whose end a marker may pin (:func:`limb_ik`).
LIMBS: tuple[tuple[str, str, str], ...] = (
    ("lshoulder", "lelbow", "lwrist"),
    ("rshoulder", "relbow", "rwrist"),
    ("lhip", "lknee", "lankle"),
    ("rhip", "rknee", "rankle"),
    ("chest", "neck", "head"),
)


def _limbs(joints: list[str], markers: list[str], chain: np.ndarray) -> list[tuple[int, int, int, int, np.ndarray]]:
    """(base, middle, end, marker, descendants of end) of each limb of :data:`LIMBS` with a marker at its end."""
    out = []
    for a, b, c in LIMBS:
        if c in markers and all(j in joints for j in (a, b, c)):
            e = joints.index(c)
            below = np.flatnonzero(chain[:, e] > 0)
            out.append((joints.index(a), joints.index(b), e, markers.index(c), below[below != e]))
    return out


@dataclass
class Reconstruction:
    """The result of :func:`reconstruct`.

    Attributes
    ----------
    positions : ndarray (T, P, 3), metres, world positions of ``joints``
    heading : ndarray (T,), radians, the root's heading
    confidence : ndarray (T,) in [0, 1]: ``1 / (1 + s)`` with
        ``s = max(novelty - 1, 0)^2 + (misfit / confidence_misfit)^2 + (reach / confidence_reach)^2
        + limit^2`` (1: the frame looks like the prior and every term is small)
    novelty : ndarray (T,), the query's mean distance to its ``k`` neighbours over the
        prior's typical one (:attr:`PosePrior.typical`; 1 typical, larger: unlike any prior pose)
    misfit : ndarray (T,), metres, RMS distance of the local model's MAP pose from the
        non-root markers (before the limbs are put on them)
    reach : ndarray (T,), metres, RMS distance left between the limb ends and their markers
        (markers beyond the performer's reach)
    limit : ndarray (T,), the worst limb's distance to its nearest prior configuration over
        ``limit_sigma`` (0 where the sides are not chosen)
    joints : tuple of str
    """

    positions: np.ndarray
    heading: np.ndarray
    confidence: np.ndarray
    novelty: np.ndarray
    misfit: np.ndarray
    reach: np.ndarray
    limit: np.ndarray
    joints: tuple[str, ...]


def reconstruct_positions(
    markers: np.ndarray,
    prior: PosePrior,
    params: ReconstructParams | None = None,
    model: ReconstructModel = MODEL,
    root_heading: np.ndarray | None = None,
    fps: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Reconstruct full poses from marker trajectories: :func:`reconstruct`'s positions
    (T, P, 3) metres and heading (T,) radians."""
    r = reconstruct(markers, prior, params, model, root_heading, fps)
    return r.positions, r.heading


def reconstruct(
    markers: np.ndarray,
    prior: PosePrior,
    params: ReconstructParams | None = None,
    model: ReconstructModel = MODEL,
    root_heading: np.ndarray | None = None,
    fps: float | None = None,
) -> Reconstruction:
    """Reconstruct full poses from marker trajectories, with a confidence per frame.

    Parameters
    ----------
    markers : ndarray of shape (T, M, 3), metres
        World positions of ``model.markers`` (which must include ``root``), y up.
    prior : PosePrior
    params : ReconstructParams
    model : ReconstructModel
    root_heading : ndarray of shape (T,), radians, optional
        The root's heading (facing ``(lhip - rhip) x up``, as :func:`facing_angles`): the
        root marker as a rigid body (a pelvis cluster), which the paper's root-normalised
        features presuppose. Without it the heading is estimated from the markers.
    fps : float, optional
        The take's frame rate (default: the prior's); scales the knee/elbow side's
        temporal term so that it means the same at any rate.

    Returns
    -------
    Reconstruction
    """
    p = params or ReconstructParams()
    mk = list(model.markers)
    markers = np.asarray(markers, np.float64)
    joints = list(prior.joints)
    if tuple(mk) != prior.markers or "root" not in mk or any(m not in joints for m in mk):
        raise DataError(f"markers {mk} must include 'root', lie in the pose joints {joints} and be the prior's")
    if markers.ndim != 3 or markers.shape[1:] != (len(mk), 3):
        raise DataError(f"markers must be (T, {len(mk)}, 3), got {markers.shape}")
    if not np.isfinite(markers).all():
        raise DataError("markers contain NaN or inf (fill gaps first)")
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise DataError(f"fps must be a positive number, got {fps}")
    fixed = root_heading is not None
    if root_heading is not None:
        root_heading = np.asarray(root_heading, np.float64)
        if root_heading.shape != (len(markers),) or not np.isfinite(root_heading).all():
            raise DataError(f"root_heading must be {len(markers)} finite angles, got shape {root_heading.shape}")
    t_len, n_j = len(markers), len(joints)
    parents = bone_parents(joints)
    fr = _Frames(
        np.array([[3 * joints.index(m) + a for a in range(3)] for m in mk]).ravel(),
        np.array([i for i, m in enumerate(mk) if m != "root"]),
        parents,
        chain_matrix(parents),
        prior.lengths,
        _limbs(joints, mk, chain_matrix(parents)),
    )
    root = markers[:, mk.index("root")]
    rel = markers - root[:, None, :]
    heading = np.zeros(t_len)
    if t_len == 0:
        z = np.zeros(0)
        return Reconstruction(np.zeros((0, n_j, 3)), heading, z, z, z, z, z, prior.joints)

    if root_heading is not None:
        heading[:] = root_heading
    from threadpoolctl import threadpool_limits

    # the solves are small (k x k): a BLAS thread pool only adds wake-ups (6 ms instead of
    # 0.3 ms per solve on a busy machine)
    with threadpool_limits(1, user_api="blas"):
        out, heading, misfit, qdist, limit = _passes(rel, root, heading, fixed, prior, fr, p, model, fps)
    world = rotate_about_y(out.reshape(t_len, n_j, 3), heading) + root[:, None, :]

    # how far the limb ends stayed from their markers (beyond the performer's reach)
    ends = [joints.index(m) for m in mk if m != "root"]
    reach = np.sqrt(np.mean(np.sum((world[:, ends] - markers[:, fr.nonroot]) ** 2, -1), 1))
    novelty = qdist / prior.typical[min(p.k, len(prior.poses), TYPICAL_K) - 1]
    s = (
        np.maximum(novelty - 1.0, 0.0) ** 2
        + (misfit / model.confidence_misfit) ** 2
        + (reach / model.confidence_reach) ** 2
        + limit**2
    )
    return Reconstruction(world, heading, 1.0 / (1.0 + s), novelty, misfit, reach, limit, prior.joints)


def _passes(
    rel: np.ndarray,
    root: np.ndarray,
    heading: np.ndarray,
    fixed: bool,
    prior: PosePrior,
    fr: _Frames,
    p: ReconstructParams,
    model: ReconstructModel,
    fps: float | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The solves of :func:`reconstruct`: heading-frame poses (T, D), heading, marker
    misfit, mean neighbour distance and limit cost per frame."""
    t_len, n_j = len(rel), len(prior.joints)
    out = np.zeros((t_len, n_j * 3))
    misfit, qdist = np.zeros(t_len), np.zeros(t_len)
    k = min(p.k, len(prior.poses))

    # a known heading: every pass queries the same neighbours, kept per frame (about 1.5 kB
    # a frame at k 128; longer takes query again)
    reuse = fixed and model.smooth_passes > 0 and t_len * k <= NEIGHBOUR_CACHE
    caches: list[dict[str, Any]] = [{} for _ in range(t_len)] if reuse else []

    def solve(t: int, guess: np.ndarray, theta: float, pred: np.ndarray | None, iters: int) -> None:
        theta = heading[t] if fixed else theta
        out[t], heading[t], misfit[t], qdist[t] = _solve_frame(
            rel[t], guess, theta, pred, prior, fr, k, model, iters, fixed, caches[t] if reuse else None
        )

    theta, guess = _initial_pose(rel[0], prior.poses, fr.sel, heading[0] if fixed else None)
    heading[0] = theta
    # the first frame starts from a database pose and has no temporal context: search more often
    solve(0, guess, theta, None, max(model.iterations, 5))
    for t in range(1, t_len):
        pred = 2 * out[t - 1] - out[t - 2] if t >= 2 else out[t - 1]
        solve(t, pred, heading[t - 1], pred, model.iterations)
    # then a short backward pass: the first frames again, predicted from the later ones
    for t in range(min(model.backward_frames, t_len - 2) - 1, -1, -1):
        pred = 2 * out[t + 1] - out[t + 2]
        solve(t, pred, heading[t + 1], pred, model.iterations)
    for _ in range(model.smooth_passes if t_len >= 3 else 0):
        first = out.copy()
        held = fixed
        if not fixed and model.heading_window > 0:
            # the estimated heading, averaged over +-heading_window seconds, is held in this pass
            heading[:] = smooth_heading(heading, max(1, int(round(model.heading_window * (fps or prior.fps)))))
            held = True
        for t in range(t_len):
            pred = 0.5 * (first[max(t - 1, 0)] + first[min(t + 1, t_len - 1)])
            if held and not fixed:
                out[t], _, misfit[t], qdist[t] = _solve_frame(
                    rel[t], pred, heading[t], pred, prior, fr, k, model, 1, True
                )
            else:
                solve(t, pred, heading[t], pred, model.iterations)
    local = out.reshape(t_len, n_j, 3)
    limit = np.zeros(t_len)
    if model.swivel_states > 1 and model.project:
        rate = prior.fps / (fps or prior.fps)
        limit = consistent_sides(local, heading, root, prior, model, rate)
    return out, heading, misfit, qdist, limit


def smooth_heading(heading: np.ndarray, half: int) -> np.ndarray:
    """Headings (T,) radians averaged (unwrapped) over ``2 * half + 1`` frames, the ends
    padded with their first/last value."""
    h = np.unwrap(np.asarray(heading, np.float64))
    if len(h) == 0 or half < 1:
        return h
    pad = np.r_[np.full(half, h[0]), h, np.full(half, h[-1])]
    return np.convolve(pad, np.ones(2 * half + 1) / (2 * half + 1), mode="valid")


def project_bones(pose: np.ndarray, fr: _Frames) -> np.ndarray:
    """Pose (D,) with every bone put on the performer's length, directions kept."""
    y = pose.reshape(-1, 3)
    v = y - y[np.maximum(fr.parents, 0)]
    n = np.linalg.norm(v, axis=1, keepdims=True)
    d = np.where(n > 1e-9, v / np.maximum(n, 1e-12), 0.0)
    d[0] = 0.0
    return cast("np.ndarray", (fr.chain @ (d * fr.lengths[:, None])).ravel())


def limb_ik(pose: np.ndarray, obs: np.ndarray, fr: _Frames) -> np.ndarray:
    """Pose (D,) with each limb's end on its marker (``obs`` (M, 3), heading frame), as
    far as the performer's bones reach: the middle joint on the circle the two bone lengths
    allow, on the side of the solved one (analytic two-bone IK); the end's descendants move
    with it."""
    y = pose.reshape(-1, 3).copy()
    for a, b, c, m, below in fr.limbs:
        l1, l2 = fr.lengths[b], fr.lengths[c]
        axis = obs[m] - y[a]
        dist = float(np.linalg.norm(axis))
        if dist < 1e-9 or l1 + l2 < 1e-9:
            continue
        u = axis / dist
        d = min(max(dist, abs(l1 - l2) + 1e-9), l1 + l2 - 1e-9) if l1 + l2 > 2e-9 else 0.0
        x = (l1 * l1 - l2 * l2 + d * d) / (2 * d) if d > 0 else 0.0
        r = np.sqrt(max(l1 * l1 - x * x, 0.0))
        side = y[b] - y[a] - np.dot(y[b] - y[a], u) * u
        n = float(np.linalg.norm(side))
        if n < 1e-9:
            side = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
            n = float(np.linalg.norm(side))
        end = y[a] + d * u
        y[below] += end - y[c]
        y[b] = y[a] + x * u + r * side / n
        y[c] = end
    return cast("np.ndarray", y.ravel())


def _solve_frame(
    rel: np.ndarray,
    guess: np.ndarray,
    theta: float,
    pred: np.ndarray | None,
    prior: PosePrior,
    fr: _Frames,
    k: int,
    model: ReconstructModel,
    iterations: int,
    fixed: bool = False,
    cache: dict[str, Any] | None = None,
) -> tuple[np.ndarray, float, float, float]:
    """One frame: kNN of the control signal, local model, MAP pose and heading (module doc).

    rel : (M, 3) markers relative to the root marker; guess, pred :
    (D,) local poses; returns the pose (D,), the heading (radians, kept if ``fixed``), the
    RMS marker misfit of the MAP pose (metres) and the query's mean neighbour distance.
    ``cache``: with a known heading the query of a frame never changes; its neighbours are
    kept there under ``"ids"``/``"dist"`` and reused by a later pass.
    """
    from ._reconstruct_kernels import map_pose

    w_m, w_s = 1.0 / model.marker_sigma**2, 1.0 / model.smooth_sigma**2
    has_pred = pred is not None
    pred_v = pred if pred is not None else guess
    qd = 0.0
    # a known heading makes the query the same in every search: one is enough
    for _ in range(1 if fixed else iterations):
        c, s = np.cos(theta), np.sin(theta)
        obs_m = np.stack([c * rel[:, 0] - s * rel[:, 2], rel[:, 1], s * rel[:, 0] + c * rel[:, 2]], 1)
        if cache is not None and "ids" in cache:
            dist, ids = cache["dist"], cache["ids"]
        else:
            q = obs_m[fr.nonroot].astype(np.float32).reshape(1, -1)
            dist, ids = prior.index.query(q, k)
            if cache is not None and fixed:
                cache["dist"], cache["ids"] = dist, ids
        ok = ids[0] >= 0
        qd = float(dist[0][ok].mean())
        nb = prior.poses[ids[0][ok]].astype(np.float64)
        guess, new_theta = map_pose(nb, fr.sel, rel, theta, pred_v, has_pred, w_m, w_s, 1 if fixed else 2)
        theta = theta if fixed else new_theta
    c, s = np.cos(theta), np.sin(theta)
    obs_m = np.stack([c * rel[:, 0] - s * rel[:, 2], rel[:, 1], s * rel[:, 0] + c * rel[:, 2]], 1)
    gap = guess[fr.sel].reshape(-1, 3)[fr.nonroot] - obs_m[fr.nonroot]
    misfit = float(np.sqrt(np.mean(np.sum(gap * gap, 1))))
    if model.project:
        guess = limb_ik(project_bones(guess, fr), obs_m, fr)
    return guess, float(theta), misfit, qd


def _initial_pose(
    rel: np.ndarray, poses: np.ndarray, sel: np.ndarray, heading: float | None = None, n_yaw: int = 24
) -> tuple[float, np.ndarray]:
    """Heading and nearest database pose for the first frame: markers (M,3) relative to the
    root are compared with every database pose's marker joints under ``n_yaw`` headings
    (only ``heading`` if given, which is returned)."""
    yaws = np.linspace(0, 2 * np.pi, n_yaw, endpoint=False) if heading is None else np.array([heading])
    cand = rotate_about_y(np.broadcast_to(rel, (n_yaw,) + rel.shape), -yaws).reshape(n_yaw, -1)
    db = poses[:, sel].astype(np.float64)
    d2 = (db * db).sum(1)[:, None] - 2 * db @ cand.T + (cand * cand).sum(1)[None, :]
    row, col = np.unravel_index(int(np.argmin(d2)), d2.shape)
    pose = poses[row].astype(np.float64)
    return (_yaw_align(pose[sel].reshape(-1, 3), rel) if heading is None else float(heading)), pose
