"""The side of each knee and elbow over a whole take (``analyses.reconstruct``).

After the per-frame solves, each knee's and elbow's middle joint is put at one of
``swivel_states`` positions on the circle its two bones allow about the line from its base
to its end, chosen by dynamic programming over the take (:func:`consistent_sides`, kernel
``_reconstruct_kernels.swivel_path``): a joint-limit cost (the distance of the limb's two
unit bone vectors to the nearest configuration of that limb in the prior), the distance from
the solved position, and the middle joint's world step between frames.
"""

from __future__ import annotations

from typing import Protocol, cast

import numpy as np

from mocapflow.framework import Index
from mocapflow.framework.normalize import rotate_about_y

from .reconstruct_prior import prior_index


class PosePrior(Protocol):
    """What the side choice reads of :class:`.reconstruct.PosePrior`."""

    @property
    def joints(self) -> tuple[str, ...]: ...
    @property
    def poses(self) -> np.ndarray: ...
    @property
    def limits(self) -> dict[tuple[int, int, int], Index]: ...


class ReconstructModel(Protocol):
    """What the side choice reads of :class:`.reconstruct.ReconstructModel`."""

    @property
    def swivel_states(self) -> int: ...
    @property
    def limit_sigma(self) -> float: ...
    @property
    def swivel_sigma(self) -> float: ...
    @property
    def swivel_step(self) -> float: ...


#: The limbs whose middle joint's side :func:`consistent_sides` chooses (the first four of
#: :data:`.reconstruct.LIMBS`).
SWIVEL_LIMBS: tuple[tuple[str, str, str], ...] = (
    ("lshoulder", "lelbow", "lwrist"),
    ("rshoulder", "relbow", "rwrist"),
    ("lhip", "lknee", "lankle"),
    ("rhip", "rknee", "rankle"),
)


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(n > 1e-12, v / np.maximum(n, 1e-12), 0.0)


def limb_configurations(poses: np.ndarray, a: int, b: int, c: int) -> np.ndarray:
    """Joint-limit features (..., 6) of poses (..., P, 3): the unit vectors from joint ``a``
    to ``b`` and from ``b`` to ``c`` (upper and lower limb) in the root's heading frame."""
    return np.concatenate([_unit(poses[..., b, :] - poses[..., a, :]), _unit(poses[..., c, :] - poses[..., b, :])], -1)


def limit_index(prior: PosePrior, a: int, b: int, c: int) -> Index:
    """The kNN index of the prior's configurations of the limb ``a, b, c`` (built once per prior)."""
    key = (a, b, c)
    if key not in prior.limits:
        y = prior.poses.reshape(len(prior.poses), -1, 3)
        index = prior_index()
        index.build(np.ascontiguousarray(limb_configurations(y, a, b, c), np.float32))
        prior.limits[key] = index
    return prior.limits[key]


def swivel_candidates(local: np.ndarray, a: int, b: int, c: int, n_states: int) -> np.ndarray:
    """Positions (T, S, 3) of the middle joint ``b`` of poses (T, P, 3) at ``S`` swivel
    angles about the line from ``a`` to ``c`` (lengths kept; state 0: where it is)."""
    base, mid, end = local[:, a], local[:, b], local[:, c]
    u = _unit(end - base)
    v = mid - base
    along = np.sum(v * u, -1, keepdims=True)
    side = v - along * u
    r = np.linalg.norm(side, axis=-1, keepdims=True)
    ref = np.where(np.abs(u[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    fallback = _unit(np.cross(u, ref))
    s0 = np.where(r > 1e-9, side / np.maximum(r, 1e-12), fallback)
    w0 = np.cross(u, s0)
    phi = 2 * np.pi * np.arange(n_states) / n_states
    rot = np.cos(phi)[None, :, None] * s0[:, None] + np.sin(phi)[None, :, None] * w0[:, None]
    return cast("np.ndarray", (base + along * u)[:, None] + r[:, None] * rot)


def consistent_sides(
    local: np.ndarray, heading: np.ndarray, root: np.ndarray, prior: PosePrior, model: ReconstructModel, rate: float
) -> np.ndarray:
    """Choose each knee's and elbow's side (in place on heading-frame poses ``local``
    (T, P, 3)) by dynamic programming over ``model.swivel_states`` positions on its IK
    circle: joint-limit cost (distance to the nearest prior configuration of the limb over
    ``limit_sigma``, squared) + distance from the solved position (``swivel_sigma``) per
    frame, weighted by ``rate`` (prior rate / take rate), + the middle joint's world step
    between frames (``swivel_step`` per prior frame) over ``rate``. Returns the worst limb's
    limit cost (T,) (distance over ``limit_sigma``) of the chosen poses."""
    from ._reconstruct_kernels import swivel_path

    joints = list(prior.joints)
    t_len, n_s = len(local), model.swivel_states
    worst = np.zeros(t_len)
    for names in SWIVEL_LIMBS:
        if not all(j in joints for j in names):
            continue
        a, b, c = (joints.index(j) for j in names)
        mids = swivel_candidates(local, a, b, c, n_s)
        cand = np.repeat(local[:, None], n_s, 1)
        cand[:, :, b] = mids
        feats = limb_configurations(cand, a, b, c).reshape(-1, 6).astype(np.float32)
        dist, _ = limit_index(prior, a, b, c).query(feats, 1)
        lim = (dist[:, 0].astype(np.float64) / model.limit_sigma).reshape(t_len, n_s)
        dev = np.sum((mids - mids[:, :1]) ** 2, -1) / model.swivel_sigma**2
        world = rotate_about_y(mids, heading) + root[:, None, :]
        path = swivel_path(rate * (lim**2 + dev), world, 1.0 / (rate * model.swivel_step**2))
        rows = np.arange(t_len)
        local[:, b] = mids[rows, path]
        worst = np.maximum(worst, lim[rows, path])
    return worst
