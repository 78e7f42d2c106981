"""A scene's animated node tree (glTF nodes, FBX models) as a :class:`Motion`.

The readers of :mod:`.gltf` and :mod:`.fbx` hand over a chain of nodes in topological
order (the skeleton's ancestors first, if any, then the skeleton), each with a rest
transform and a per-frame local transform (translation, rotation, uniform scale).
:func:`motion_from_nodes` composes them (``p = p_parent + s_parent * W_parent t``,
``W = W_parent r``, ``s = s_parent * s_local``) and re-expresses the skeleton with
identity rest rotations, as every mocapflow motion is (BVH's convention):

* ``offsets[j]`` is the rest-pose vector from the parent joint to joint ``j`` in world
  axes (scale included), so the rest pose is all-identity rotations;
* ``rotations[t, j] = Wrest_parent * r_j(t) * Wrest_j^-1`` (root: ``W_0(t) * Wrest_0^-1``,
  ancestors' transforms included), which gives world rotations ``W_j(t) Wrest_j^-1`` and
  exactly the file's joint positions;
* ``Skeleton.meta["rest_rotations"]`` keeps the file's rest world rotations, so the glTF
  writer can restore the rig's bone orientations;
* translations that move (other than the root's) become ``Motion.local_translations``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from mocapflow.framework import quaternions as quat
from mocapflow.framework.errors import ParseError
from mocapflow.framework.joints import canonical_map
from mocapflow.framework.motion import Motion
from mocapflow.framework.plugins import registered_joint_maps
from mocapflow.framework.skeleton import Skeleton

from ._common import MAX_METRES

#: Relative tolerance of "uniform" scale and of "constant" translation.
SCALE_TOL = 1e-4
MOVE_TOL = 1e-6  # metres


def common_root(
    parent_of: Callable[[int], int | None],
    joints: Iterable[int],
    max_depth: int,
    error: Callable[[str], Exception],
) -> tuple[int, set[int], list[int]] | None:
    """The lowest common ancestor of ``joints`` in a hierarchy given by ``parent_of``
    (``None``: no parent), the nodes on the paths from it to the joints (itself included)
    and its ancestors from the top; ``None`` when the joints have no common ancestor.

    Iterative and linear: the first joint's chain is walked once (at most ``max_depth``
    nodes), every other walk stops at a node already seen, so each node is visited once
    whatever the shape (a 100,000-deep chain, 100,000 leaves). A cycle or a chain deeper
    than ``max_depth`` raises ``error(message)``."""
    order = sorted(joints)
    chain: list[int] = []  # the first joint and its ancestors, upwards
    pos: dict[int, int] = {}
    m: int | None = order[0]
    while m is not None:
        if m in pos:
            raise error(f"node {m}: its ancestors form a cycle; expected a tree")
        if len(chain) >= max_depth:
            raise error(f"node {order[0]}: more than {max_depth:,} ancestors; expected a shallower hierarchy")
        pos[m] = len(chain)
        chain.append(m)
        m = parent_of(m)
    meets: dict[int, int] = {}  # node below the chain -> index in the chain its ancestors reach
    top = 0
    for j in order[1:]:
        walk: dict[int, None] = {}
        m = j
        while True:
            if m is None:
                return None
            if m in pos:
                e = pos[m]
                break
            if m in meets:
                e = meets[m]
                break
            if m in walk:
                raise error(f"node {m}: its ancestors form a cycle; expected a tree")
            walk[m] = None
            m = parent_of(m)
        for w in walk:
            meets[w] = e
        top = max(top, e)
    return chain[top], set(chain[: top + 1]) | set(meets), chain[top + 1 :][::-1]


def unique_names(names: list[str]) -> list[str]:
    """Names made unique with ``_2``, ``_3``... suffixes (in order of appearance)."""
    seen: set[str] = set()
    out = []
    for n in names:
        m, k = n, 2
        while m in seen:
            m, k = f"{n}_{k}", k + 1
        seen.add(m)
        out.append(m)
    return out


def uniform_scale(path: Path, name: str, s: np.ndarray) -> np.ndarray:
    """The uniform factor of scale vectors ``(..., 3)``; ParseError for a non-uniform or
    non-positive scale (a skeleton's joints cannot shear)."""
    s = np.asarray(s, dtype=float)
    m: np.ndarray = s.mean(axis=-1)
    if (
        not np.all(np.isfinite(s))
        or np.any(m <= 0)
        or np.any(np.abs(s - m[..., None]) > SCALE_TOL * np.abs(m[..., None]))
    ):
        bad = s.reshape(-1, 3)[0] if s.ndim > 1 else s
        raise ParseError(path, None, f"node {name!r}: expected a positive uniform scale, found {bad.tolist()}")
    return m


def motion_from_nodes(
    path: Path,
    *,
    names: list[str],
    parents: np.ndarray,
    first_joint: int,
    rest_t: np.ndarray,
    rest_r: np.ndarray,
    rest_s: np.ndarray,
    t: np.ndarray,
    r: np.ndarray,
    s: np.ndarray,
    fps: float,
    fmt: str,
    name: str,
    meta: dict[str, Any],
    ignore_parent_scale: np.ndarray | None = None,
) -> Motion:
    """The skeleton of nodes ``first_joint..`` (nodes before it are ancestors of
    ``first_joint``; their transforms, animated or not, move the root) as a Motion.
    ``rest_*``: (N, 3) / (N, 4) / (N,) rest translation, rotation, uniform scale;
    ``t, r, s``: the same per frame, (F, N, ...) (views of node-major arrays are fastest).
    Translations in metres, world y-up; rotations unit quaternions (w, x, y, z).
    ``ignore_parent_scale`` (N,) bool: nodes whose rotation and scale do not inherit
    their parent's own scale (FBX ``InheritType`` Rrs, Maya's segment scale compensate);
    their translation is still scaled by it."""
    n = len(names)
    ign = np.zeros(n, dtype=bool) if ignore_parent_scale is None else np.asarray(ignore_parent_scale, dtype=bool)
    rest_r = quat.normalize(rest_r)
    rpos, rrot, rscl = np.empty((n, 3)), np.empty((n, 4)), np.empty(n)
    for k in range(n):
        p = parents[k]
        if p < 0:
            rpos[k], rrot[k], rscl[k] = rest_t[k], rest_r[k], rest_s[k]
        else:
            rpos[k] = rpos[p] + rscl[p] * quat.rotate(rrot[p], rest_t[k])
            rrot[k] = quat.mul(rrot[p], rest_r[k])
            rscl[k] = (rscl[p] / rest_s[p] if ign[k] else rscl[p]) * rest_s[k]
    j0 = first_joint
    jparents = np.array([-1] + [int(parents[k]) - j0 for k in range(j0 + 1, n)], dtype=np.int64)
    if np.any(jparents[1:] < 0):
        raise ParseError(path, None, "expected the skeleton's joints to descend from one root")
    still = j0 == 0 or all(np.ptp(x[:, :j0], axis=0).max(initial=0.0) == 0 for x in (t, r, s))
    if still and np.ptp(s, axis=0).max(initial=0.0) == 0 and np.array_equal(s[0], rest_s):
        root_t, loc, offsets, local_t = _linear(rpos, rrot, rscl, parents, j0, t, r)
    else:
        root_t, loc, offsets, local_t = _general(rpos, rrot, rscl, parents, jparents, j0, t, r, s, ign)
    big = max(np.abs(root_t).max(initial=0.0), np.abs(offsets).sum(axis=0).max(initial=0.0))
    if local_t is not None:
        big = max(big, np.abs(local_t).max(initial=0.0))
    if not (np.isfinite(big) and np.all(np.isfinite(loc))):
        raise ParseError(path, None, "expected finite joint transforms after composing the node transforms")
    if big > MAX_METRES:
        raise ParseError(path, None, f"expected joint positions within {MAX_METRES:g} m, found larger ones")
    jnames = tuple(names[j0:])
    skeleton = Skeleton(
        names=jnames,
        parents=jparents,
        offsets=offsets,
        canonical=canonical_map(jnames, None, registered_joint_maps()),  # any dialect: rigs come from any tool
        rotation_orders=("",) * len(jnames),
        name=name,
        meta={"format": fmt, "rest_rotations": rrot[j0:].round(12).tolist()},
    )
    return Motion(
        skeleton=skeleton,
        root_translation=root_t,
        rotations=loc,
        fps=fps,
        name=name,
        metadata=meta,
        local_translations=local_t,
    )


def _qmat(q: np.ndarray, right: bool) -> np.ndarray:
    """4x4 matrices of ``p -> q p`` (``right``: ``p -> p q``) for quaternions (..., 4)."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    if right:
        rows = [[w, -x, -y, -z], [x, w, z, -y], [y, -z, w, x], [z, y, -x, w]]
    else:
        rows = [[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def _linear(
    rpos: np.ndarray, rrot: np.ndarray, rscl: np.ndarray, parents: np.ndarray, j0: int, t: np.ndarray, r: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Constant scales and still ancestors: every output is a constant linear map of the
    file's local values (``r' = Wrest_p r Wrest_j^-1``, ``t' = s_p Wrest_p t``)."""
    n = len(parents)
    jn = np.arange(j0, n)
    wpar = np.array([rrot[parents[k]] if parents[k] >= 0 else quat.identity() for k in jn])
    spar = np.array([rscl[parents[k]] if parents[k] >= 0 else 1.0 for k in jn])
    m = _qmat(wpar, False) @ _qmat(quat.conjugate(rrot[j0:]), True)  # (J, 4, 4)
    loc = np.empty((t.shape[0], n - j0, 4))
    for j in range(n - j0):
        loc[:, j] = r[:, j0 + j] @ m[j].T
    a = parents[j0]
    root_t = t[:, j0] if a < 0 else rpos[a] + rscl[a] * quat.rotate(rrot[a], t[:, j0])
    offsets = np.zeros((len(jn), 3))
    offsets[1:] = rpos[j0 + 1 :] - rpos[parents[j0 + 1 :]]
    moving = [k for k in range(1, len(jn)) if np.ptp(t[:, j0 + k], axis=0).max() > 0]
    local_t = None
    if moving:
        rm = quat.to_matrix(wpar) * spar[:, None, None]
        lt = {k: t[:, j0 + k] @ rm[k].T for k in moving}
        lt = {k: v for k, v in lt.items() if np.abs(v - offsets[k]).max() > MOVE_TOL}
        if lt:
            local_t = np.broadcast_to(offsets, (t.shape[0], len(jn), 3)).copy()
            for k, v in lt.items():
                local_t[:, k] = v
    return root_t, loc, offsets, local_t


def _general(
    rpos: np.ndarray,
    rrot: np.ndarray,
    rscl: np.ndarray,
    parents: np.ndarray,
    jparents: np.ndarray,
    j0: int,
    t: np.ndarray,
    r: np.ndarray,
    s: np.ndarray,
    ign: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Any scales and ancestors: full forward kinematics per frame, then
    ``W' = W Wrest^-1`` and ``r'_j = W'_p^-1 W'_j``."""
    n_frames, n = t.shape[0], len(parents)
    r = quat.normalize(r)
    pos = np.empty((n_frames, n, 3))
    rot = np.empty((n_frames, n, 4))
    scl = np.empty((n_frames, n))
    for k in range(n):
        p = parents[k]
        if p < 0:
            pos[:, k], rot[:, k], scl[:, k] = t[:, k], r[:, k], s[:, k]
        else:
            pos[:, k] = pos[:, p] + scl[:, p, None] * quat.rotate(rot[:, p], t[:, k])
            rot[:, k] = quat.mul(rot[:, p], r[:, k])
            scl[:, k] = (scl[:, p] / s[:, p] if ign[k] else scl[:, p]) * s[:, k]
    wnew = quat.mul(rot[:, j0:], quat.conjugate(rrot[j0:]))
    loc = np.empty_like(wnew)
    loc[:, 0] = wnew[:, 0]
    nj = n - j0
    offsets = np.zeros((nj, 3))
    moving: dict[int, np.ndarray] = {}
    for j in range(1, nj):
        p = int(jparents[j])
        loc[:, j] = quat.mul(quat.conjugate(wnew[:, p]), wnew[:, j])
        offsets[j] = rpos[j0 + j] - rpos[j0 + p]
        lt = quat.rotate(quat.conjugate(wnew[:, p]), pos[:, j0 + j] - pos[:, j0 + p])
        if np.abs(lt - offsets[j]).max(initial=0.0) > MOVE_TOL:
            moving[j] = lt
    local_t = None
    if moving:  # joints whose translation is constant keep their offset
        local_t = np.broadcast_to(offsets, (n_frames, nj, 3)).copy()
        for j, lt in moving.items():
            local_t[:, j] = lt
    return pos[:, j0], loc, offsets, local_t
