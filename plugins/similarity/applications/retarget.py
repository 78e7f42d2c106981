"""Joint rotations from target joint positions: the Output Motion step of ``analyses.reconstruct``.

Reconstructed canonical joint positions are turned into joint rotations of a skeleton by
aiming every bone at its reconstructed canonical descendants (minimal rotation for one,
Kabsch for several; all frames at once), so ``formats.export`` writes them as BVH/AMC.

Any rig: joints above the canonical root (a Bandai-Namco ``joint_Root`` on the floor) keep
their rest rotation and carry the root to its target; joints between canonical ones
(a BVH ``Neck1``, an ASF ``lhipjoint``) are aimed through. On an ASF skeleton every joint
turns only about its ``dof`` axes, as AMC stores it: a dof-less bone keeps its rest
rotation, a hinge (one dof: CMU/HDM05 elbows and knees) bends about its axis by the angle
that reaches its target, with the bone above it twisted so that the target lies in the
hinge's plane, and a two-dof joint keeps the part of its rotation its dofs express (the
bones below aim from where it leaves them).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, cast

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
    metadata: dict[str, Any] | None = None,
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
    pos = np.array(positions, np.float64)  # a copy: limb middles are moved (two-bone IK)
    t_len = len(pos)
    r = skeleton.canonical.get("root", -1)
    if r < 0 or "root" not in joints:
        raise DataError(f"skeleton {skeleton.name!r}: reconstruction needs a canonical root joint")
    above = set(_ancestors(skeleton, r))
    aims = _aim_targets(skeleton, joints)
    for j in above:
        aims[j] = []  # joints above the root keep their rest rotation
    dofs = _dofs(skeleton)
    limbs = _limbs(skeleton, joints)
    glob = np.empty((t_len, skeleton.n_joints, 4))
    world = np.empty((t_len, skeleton.n_joints, 3))
    local = np.empty_like(glob)
    # joint 0 placed so that the canonical root (below rest-rotated ancestors) lands on its target
    lift = sum((skeleton.offsets[a] for a in _ancestors(skeleton, r)[1:] + ([r] if r else [])), np.zeros(3))
    world[:, 0] = pos[:, list(joints).index("root")] - lift
    for j in range(skeleton.n_joints):
        par = skeleton.parents[j]
        g_par = quat.identity((t_len,)) if par < 0 else glob[:, par]
        if par >= 0:
            world[:, j] = world[:, par] + quat.rotate(g_par, np.broadcast_to(skeleton.offsets[j], (t_len, 3)))
        if not aims[j]:
            glob[:, j] = g_par
        elif len(aims[j]) == 1:
            col, v = aims[j][0]
            if j in limbs:  # the middle joint moved so that the limb's end reaches its target
                c_mid, c_end, l1, l2 = limbs[j]
                pos[:, c_mid] = two_bone_middle(world[:, j], pos[:, c_end], pos[:, c_mid], l1, l2)
            a = quat.rotate(g_par, np.broadcast_to(v, (t_len, 3)))
            glob[:, j] = quat.mul(_between(a, pos[:, col] - world[:, j]), g_par)
            hinge = _hinge_below(skeleton, j, col, aims, dofs, joints)
            if hinge is not None and dofs[j] is None:
                glob[:, j] = _twist_to_hinge(glob[:, j], world[:, j], pos, col, hinge, skeleton)
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
        dof = dofs[j]
        if par >= 0 and dof is not None:
            local[:, j] = _on_dofs(local[:, j], skeleton, j, dof, g_par, world[:, j], pos, aims[j])
            glob[:, j] = quat.mul(g_par, local[:, j])
    local = quat.make_continuous(quat.normalize(local), axis=0)
    return Motion(skeleton, world[:, 0], local, fps, name=name, metadata=dict(metadata or {}))


#: (base, middle, end) canonical chains whose end the output puts on its target by two-bone IK.
LIMB_CHAINS: tuple[tuple[str, str, str], ...] = (
    ("lshoulder", "lelbow", "lwrist"),
    ("rshoulder", "relbow", "rwrist"),
    ("lhip", "lknee", "lankle"),
    ("rhip", "rknee", "rankle"),
)


def _limbs(skeleton: Skeleton, joints: Sequence[str]) -> dict[int, tuple[int, int, float, float]]:
    """Base joint -> (middle column, end column, upper and lower bone lengths) of each
    :data:`LIMB_CHAINS` chain that the skeleton holds as parent -> child -> grandchild."""
    out = {}
    for a, b, c in LIMB_CHAINS:
        if all(n in skeleton.canonical and n in joints for n in (a, b, c)):
            ia, ib, ic = (skeleton.canonical[n] for n in (a, b, c))
            if skeleton.parents[ib] == ia and skeleton.parents[ic] == ib:
                l1, l2 = (float(np.linalg.norm(skeleton.offsets[i])) for i in (ib, ic))
                if l1 > 1e-9 and l2 > 1e-9:
                    out[ia] = (list(joints).index(b), list(joints).index(c), l1, l2)
    return out


def two_bone_middle(base: np.ndarray, end: np.ndarray, hint: np.ndarray, l1: float, l2: float) -> np.ndarray:
    """Middle joints (T,3) of two-bone chains from ``base`` to ``end`` (T,3) with bones ``l1``,
    ``l2``: on the circle the lengths allow, on the side of ``hint`` (the solved middle);
    a target out of reach gets the chain stretched towards it."""
    axis = end - base
    dist = np.linalg.norm(axis, axis=1, keepdims=True)
    u = axis / np.maximum(dist, 1e-12)
    d = np.clip(dist, abs(l1 - l2) + 1e-9, l1 + l2 - 1e-9)
    x = (l1 * l1 - l2 * l2 + d * d) / (2 * d)
    r = np.sqrt(np.maximum(l1 * l1 - x * x, 0.0))
    side = hint - base
    side = side - (side * u).sum(1, keepdims=True) * u
    n = np.linalg.norm(side, axis=1, keepdims=True)
    fallback = np.cross(u, np.where(np.abs(u[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]]))
    side = np.where(n > 1e-9, side / np.maximum(n, 1e-12), fallback / np.linalg.norm(fallback, axis=1, keepdims=True))
    return cast("np.ndarray", base + x * u + r * side)


def _ancestors(skeleton: Skeleton, j: int) -> list[int]:
    """Joints from joint 0 down to ``j``'s parent."""
    out = []
    while skeleton.parents[j] >= 0:
        j = int(skeleton.parents[j])
        out.append(j)
    return out[::-1]


def _dofs(skeleton: Skeleton) -> list[str | None]:
    """Per joint: its rotation axes (``"x"``, ``"xz"``, ``""``) where an ASF skeleton restricts
    them to fewer than three, else None (free)."""
    if skeleton.meta.get("format") != "asf" or skeleton.axes is None or not skeleton.channels:
        return [None] * skeleton.n_joints
    out: list[str | None] = []
    for j in range(skeleton.n_joints):
        ch = "".join(c[1].lower() for c in skeleton.channels[j] if c[:1].lower() == "r")
        out.append(None if j == 0 or len(ch) == 3 else ch)
    return out


def _axis(skeleton: Skeleton, j: int, dof: str) -> np.ndarray:
    """Unit axis (3,) of a one-dof joint in its parent's frame (the ASF axis frame's axis)."""
    e = np.zeros(3)
    e["xyz".index(dof)] = 1.0
    assert skeleton.axes is not None
    return quat.rotate(skeleton.axes[j], e)


def _hinge_below(
    skeleton: Skeleton, j: int, col: int, aims: list[Any], dofs: list[str | None], joints: Sequence[str]
) -> tuple[int, int, np.ndarray] | None:
    """(hinge joint, its target column, its rest vector) when ``j`` aims straight at a one-dof
    child that aims at one target (an ASF humerus above its elbow), else None."""
    kids = [c for c in skeleton.children(j) if skeleton.canonical.get(joints[col]) == c]
    if len(kids) != 1:
        return None
    c = kids[0]
    d = dofs[c]
    if d is None or len(d) != 1 or len(aims[c]) != 1:
        return None
    return c, aims[c][0][0], aims[c][0][1]


def _twist_to_hinge(
    g: np.ndarray, origin: np.ndarray, pos: np.ndarray, col: int, hinge: tuple[int, int, np.ndarray], skeleton: Skeleton
) -> np.ndarray:
    """``g`` (T,4) twisted about its bone (origin -> target ``col``) so that the hinge's own
    target lies on the cone its bone sweeps about the hinge axis (a plane when the bone is
    perpendicular to the axis): the root of the twist equation nearer to no twist."""
    c, col_g, v = hinge
    d = _dofs(skeleton)[c]
    assert d is not None
    k = float(np.dot(_axis(skeleton, c, d), v / max(float(np.linalg.norm(v)), 1e-12)))  # the hinge's cone
    u = pos[:, col] - origin
    u = u / np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
    a0 = quat.rotate(g, np.broadcast_to(_axis(skeleton, c, d), u.shape))
    w = pos[:, col_g] - pos[:, col]
    ua, uw = (u * a0).sum(1), (u * w).sum(1)
    big_a = (a0 * w).sum(1) - ua * uw
    big_b = (np.cross(u, a0) * w).sum(1)
    big_c = ua * uw - k * np.linalg.norm(w, axis=1)
    rad = np.hypot(big_a, big_b)
    star = np.arctan2(big_b, big_a)
    off = np.arccos(np.clip(-big_c / np.maximum(rad, 1e-12), -1.0, 1.0))
    roots = np.stack([star + off, star - off], 1)
    roots = (roots + np.pi) % (2 * np.pi) - np.pi
    psi = roots[np.arange(len(roots)), np.abs(roots).argmin(1)]
    psi = np.where(rad > 1e-9, psi, 0.0)
    return quat.mul(quat.from_axis_angle(u, psi), g)


def _on_dofs(
    q: np.ndarray,
    skeleton: Skeleton,
    j: int,
    dof: str,
    g_par: np.ndarray,
    origin: np.ndarray,
    pos: np.ndarray,
    aims: list[Any],
) -> np.ndarray:
    """Local rotations ``q`` (T,4) of joint ``j`` restricted to its ASF dofs: identity for
    none; for one dof aiming at one target, the angle about the axis that turns the bone
    toward it; otherwise the dofs' part of ``q`` (the AMC writer's decomposition)."""
    t_len = len(q)
    if not dof:
        return quat.identity((t_len,))
    if len(dof) == 1 and len(aims) == 1:
        col, v = aims[0]
        a = quat.rotate(g_par, np.broadcast_to(_axis(skeleton, j, dof), (t_len, 3)))
        vw = quat.rotate(g_par, np.broadcast_to(v, (t_len, 3)))
        w = pos[:, col] - origin
        vp = vw - (vw * a).sum(1, keepdims=True) * a
        wp = w - (w * a).sum(1, keepdims=True) * a
        theta = np.arctan2((np.cross(vp, wp) * a).sum(1), (vp * wp).sum(1))
        return quat.from_axis_angle(np.broadcast_to(_axis(skeleton, j, dof), (t_len, 3)), theta)
    assert skeleton.axes is not None
    c = np.broadcast_to(skeleton.axes[j], q.shape)
    m = quat.mul(quat.mul(quat.conjugate(c), q), c)
    ang = quat.euler_extrinsic_inverse(m, dof, degrees=False)
    if len(dof) == 2 and len(aims) == 1:  # two dofs aiming one bone: the exact aim nearest the projection
        col, v = aims[0]
        vv = quat.rotate(quat.conjugate(c), np.broadcast_to(v / np.linalg.norm(v), (t_len, 3)))
        w = quat.rotate(quat.conjugate(quat.mul(g_par, c)), pos[:, col] - origin)
        w = w / np.maximum(np.linalg.norm(w, axis=1, keepdims=True), 1e-12)
        a, b = (np.eye(3)["xyz".index(x)] for x in dof)
        # R_b(beta) R_a(alpha) v = w: first the a-component of R_b(-beta) w must be v's
        big_a, big_b = w @ a, -(np.cross(b, w) @ a)
        rad = np.hypot(big_a, big_b)
        star = np.arctan2(big_b, big_a)
        off = np.arccos(np.clip((vv @ a) / np.maximum(rad, 1e-12), -1.0, 1.0))
        roots = np.stack([star + off, star - off], 1)
        near = np.abs((roots - ang[:, 1:2] + np.pi) % (2 * np.pi) - np.pi).argmin(1)
        beta = roots[np.arange(t_len), near]
        x = quat.rotate(quat.from_axis_angle(np.broadcast_to(b, (t_len, 3)), -beta), w)
        vp = vv - (vv @ a)[:, None] * a
        xp = x - (x @ a)[:, None] * a
        alpha = np.arctan2(np.cross(vp, xp) @ a, (vp * xp).sum(1))
        ok = rad > 1e-9
        ang = np.where(ok[:, None], np.stack([alpha, beta], 1), ang)
    m = quat.euler_extrinsic(ang, dof, degrees=False)
    return quat.mul(quat.mul(c, m), quat.conjugate(c))


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


__all__ = ["positions_to_motion", "two_bone_middle"]
