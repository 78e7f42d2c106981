"""Joint rotations from target joint positions: the Output Motion step of ``analyses.reconstruct``.

Reconstructed canonical joint positions are turned into joint rotations of a skeleton by
aiming every bone at its reconstructed canonical descendants (minimal rotation for one,
Kabsch for several; all frames at once), so ``formats.export`` writes them as BVH/AMC.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mocapflow.framework import DataError, Motion, Skeleton
from mocapflow.framework import quaternions as quat


def _aim_targets(skeleton: Skeleton, joints: Sequence[str]) -> list[list[tuple[int, np.ndarray]]]:
    """Per joint: (pose column, rest vector from the joint) of the nearest canonical
    descendant in each child subtree (the bones that joint's rotation must aim)."""
    col = {skeleton.canonical[j]: i for i, j in enumerate(joints) if j in skeleton.canonical}
    children = [skeleton.children(j) for j in range(skeleton.n_joints)]
    aims: list[list[tuple[int, np.ndarray]]] = []
    for j in range(skeleton.n_joints):
        found = []
        for c in children[j]:
            frontier = [(c, skeleton.offsets[c])]
            while frontier:  # breadth first: the nearest canonical joint of this subtree
                hit = [(n, v) for n, v in frontier if n in col]
                if hit:
                    found += [(col[n], v) for n, v in hit]
                    break
                frontier = [(g, v + skeleton.offsets[g]) for n, v in frontier for g in children[n]]
        aims.append([(i, v) for i, v in found if np.linalg.norm(v) > 1e-9])
    return aims


def positions_to_motion(
    skeleton: Skeleton,
    positions: np.ndarray,
    joints: Sequence[str],
    fps: float,
    name: str = "",
    metadata: dict | None = None,
) -> Motion:
    """Joint rotations of ``skeleton`` that place its bones along target positions.

    Every joint is turned, for all frames at once, so that its rest bone vectors point at
    the target positions of its nearest canonical descendants: the minimal rotation from
    the inherited direction for one descendant (twist kept from the parent), a Kabsch fit of
    the directions for several (root, chest). Joints without canonical descendants keep
    their rest rotation. Bone lengths stay the skeleton's.

    Parameters
    ----------
    positions : ndarray of shape (T, P, 3), metres
        World targets of canonical ``joints`` (must include ``root``, the skeleton's joint 0).
    """
    pos = np.asarray(positions, np.float64)
    t_len = len(pos)
    if skeleton.canonical.get("root") != 0 or "root" not in joints:
        raise DataError(f"skeleton {skeleton.name!r}: reconstruction needs the canonical root at joint 0")
    aims = _aim_targets(skeleton, joints)
    glob = np.empty((t_len, skeleton.n_joints, 4))
    world = np.empty((t_len, skeleton.n_joints, 3))
    local = np.empty_like(glob)
    world[:, 0] = pos[:, list(joints).index("root")]
    for j in range(skeleton.n_joints):
        par = skeleton.parents[j]
        g_par = quat.identity((t_len,)) if par < 0 else glob[:, par]
        if par >= 0:
            world[:, j] = world[:, par] + quat.rotate(g_par, np.broadcast_to(skeleton.offsets[j], (t_len, 3)))
        if not aims[j]:
            glob[:, j] = g_par
        elif len(aims[j]) == 1:
            col, v = aims[j][0]
            a = quat.rotate(g_par, np.broadcast_to(v, (t_len, 3)))
            glob[:, j] = quat.mul(_between(a, pos[:, col] - world[:, j]), g_par)
        else:
            h = np.zeros((t_len, 3, 3))
            for col, v in aims[j]:
                w = pos[:, col] - world[:, j]
                w = w / np.maximum(np.linalg.norm(w, axis=1, keepdims=True), 1e-12)
                h += (v / np.linalg.norm(v))[None, :, None] * w[:, None, :]
            u, _, vt = np.linalg.svd(h)
            d = np.sign(np.linalg.det(np.swapaxes(vt, 1, 2) @ np.swapaxes(u, 1, 2)))
            fix = np.ones((t_len, 3))
            fix[:, 2] = d
            rot = np.swapaxes(vt, 1, 2) @ (fix[:, :, None] * np.swapaxes(u, 1, 2))
            glob[:, j] = quat.from_matrix(rot)
        local[:, j] = glob[:, j] if par < 0 else quat.mul(quat.conjugate(g_par), glob[:, j])
    local = quat.make_continuous(quat.normalize(local), axis=0)
    return Motion(skeleton, world[:, 0], local, fps, name=name, metadata=dict(metadata or {}))


def _between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Minimal rotations (T,4) taking directions ``a`` onto ``b`` (T,3); identity if degenerate."""
    a = a / np.maximum(np.linalg.norm(a, axis=1, keepdims=True), 1e-12)
    b = b / np.maximum(np.linalg.norm(b, axis=1, keepdims=True), 1e-12)
    q = np.concatenate([1.0 + (a * b).sum(1, keepdims=True), np.cross(a, b)], 1)
    # opposite directions: any axis perpendicular to a
    opp = q[:, 0] < 1e-9
    if opp.any():
        perp = np.cross(a[opp], np.array([1.0, 0.0, 0.0]))
        small = np.linalg.norm(perp, axis=1) < 1e-6
        perp[small] = np.cross(a[opp][small], np.array([0.0, 1.0, 0.0]))
        q[opp] = np.concatenate([np.zeros((opp.sum(), 1)), perp], 1)
    return quat.normalize(q)


__all__ = ["positions_to_motion"]
