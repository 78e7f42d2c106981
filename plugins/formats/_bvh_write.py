"""BVH writer (see :mod:`mocapflow.plugins.formats.bvh` for the conventions)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mocapflow.framework import quaternions as quat
from mocapflow.framework.motion import Motion
from mocapflow.framework.skeleton import Skeleton

from . import _euler_branch as euler_branch


def write_bvh(motion: Motion, path: str | Path, precision: int = 10, default_order: str = "zyx") -> None:
    """Write a motion as BVH (file units: metres divided by the source scale, if any), with
    ``precision`` significant digits per value.

    A skeleton read from BVH keeps its channel layout (order and position channels);
    others get ``Xposition Yposition Zposition`` on the root and three rotation channels
    in ``default_order`` on every other joint, except leaves named ``*_end``, which are
    written as ``End Site``; other leaves get a zero-offset ``End Site`` below them. A
    static root the reader dropped (``meta["collapsed_root"]``) is written back above the
    root, with its own name, offset, channels and values. Angles are continuous, and in the
    source file's Euler branch for a BVH source (:mod:`._euler_branch`).
    """
    if motion.skeleton.meta.get("collapsed_root"):
        motion = restore_collapsed_root(motion)
    sk = motion.skeleton
    from_bvh = sk.meta.get("format") == "bvh" and len(sk.channels) == sk.n_joints
    scl = float(sk.meta.get("scale", 1.0)) if from_bvh else 1.0
    nj = sk.n_joints
    has_kids = np.zeros(nj, bool)
    has_kids[sk.parents[1:]] = True
    chans: list[list[str]] = []
    for j in range(nj):
        if from_bvh:
            chans.append(list(sk.channels[j]))
        elif j == 0:
            chans.append(["Xposition", "Yposition", "Zposition"] + [f"{a.upper()}rotation" for a in default_order])
        elif has_kids[j] or not sk.names[j].lower().endswith("_end"):
            chans.append([f"{a.upper()}rotation" for a in default_order])
        else:
            chans.append([])
    lt = motion.local_translations
    cols: list[np.ndarray] = []
    for j in range(nj):
        rot_ch = [c for c in chans[j] if c[1:].lower() == "rotation"]
        ang = _angles(motion, j, rot_ch, from_bvh)
        r = 0
        for c in chans[j]:
            a = "xyz".index(c[0].lower())
            if c[1:].lower() == "rotation":
                assert ang is not None  # a joint with rotation channels has their angles
                cols.append(ang[:, r])
                r += 1
            elif j == 0:
                cols.append(motion.root_translation[:, a] / scl)
            else:
                cols.append((lt[:, j, a] if lt is not None else np.full(motion.n_frames, sk.offsets[j, a])) / scl)
    lines = ["HIERARCHY"]
    g = f"%.{precision}g"

    def emit(j: int, depth: int) -> None:
        ind = "\t" * depth
        off = " ".join(g % v for v in sk.offsets[j] / scl)
        if j > 0 and not chans[j] and not has_kids[j]:
            lines.extend([f"{ind}End Site", f"{ind}{{", f"{ind}\tOFFSET {off}", f"{ind}}}"])
            return
        lines.append(f"{ind}{'ROOT' if j == 0 else 'JOINT'} {sk.names[j]}")
        lines.extend([f"{ind}{{", f"{ind}\tOFFSET {off}"])
        if chans[j]:
            lines.append(f"{ind}\tCHANNELS {len(chans[j])} {' '.join(chans[j])}")
        for k in sk.children(j):
            emit(k, depth + 1)
        if not has_kids[j]:  # a leaf joint with channels: BVH wants an End Site below it
            lines.extend([f"{ind}\tEnd Site", f"{ind}\t{{", f"{ind}\t\tOFFSET 0 0 0", f"{ind}\t}}"])
        lines.append(f"{ind}}}")

    emit(0, 0)
    lines += ["MOTION", f"Frames: {motion.n_frames}", f"Frame Time: {g % (1.0 / motion.fps)}"]
    table = np.column_stack(cols) if cols else np.zeros((motion.n_frames, 0))
    row = " ".join([g] * table.shape[1])
    body = "\n".join(row % tuple(r) for r in table.tolist())
    Path(path).write_text("\n".join(lines) + "\n" + body + "\n", encoding="latin-1")


def _angles(motion: Motion, j: int, rot_ch: list[str], from_bvh: bool) -> np.ndarray | None:
    """Euler angles of joint ``j`` for its rotation channels: continuous, in the source's
    branch when the source is a BVH file with these channels."""
    if not rot_ch:
        return None
    name = motion.skeleton.names[j]
    ang = quat.to_euler(motion.rotations[:, j], "".join(c[0].lower() for c in rot_ch))
    keys = [f"{name}.{c}" for c in rot_ch]
    return euler_branch.apply(ang, name, keys, motion.metadata if from_bvh else {}, motion.fps)


def restore_collapsed_root(motion: Motion) -> Motion:
    """The motion with the static root the BVH reader dropped (``skeleton.meta["collapsed_root"]``)
    put back as joint 0: same world positions, the file's own joint names and count."""
    sk = motion.skeleton
    info = sk.meta["collapsed_root"]
    scl = float(sk.meta.get("scale", 1.0))
    r0 = np.asarray(info["rotation"], float)
    t0 = np.asarray(info["translation"], float) * scl
    n, nj = motion.n_frames, sk.n_joints
    meta = {k: v for k, v in sk.meta.items() if k != "collapsed_root"}
    skeleton = Skeleton(
        names=(str(info["name"]), *sk.names),
        parents=np.r_[-1, sk.parents + 1],
        offsets=np.vstack([np.asarray(info["offset"], float) * scl, sk.offsets]),
        canonical={k: v + 1 for k, v in sk.canonical.items()},
        rotation_orders=("".join(c[0].lower() for c in info["channels"] if c[1:].lower() == "rotation"),)
        + tuple(sk.rotation_orders),
        channels=(tuple(info["channels"]), *sk.channels),
        name=sk.name,
        meta=meta,
    )
    r0_inv = quat.conjugate(r0)
    rot = np.concatenate(
        [np.broadcast_to(r0, (n, 1, 4)), quat.mul(r0_inv, motion.rotations[:, :1]), motion.rotations[:, 1:]], axis=1
    )
    lt = np.empty((n, nj + 1, 3))
    lt[:] = skeleton.offsets
    if motion.local_translations is not None:
        lt[:, 2:] = motion.local_translations[:, 1:]
    lt[:, 1] = quat.rotate(r0_inv, motion.root_translation - t0)
    return motion.with_arrays(
        skeleton=skeleton, root_translation=np.broadcast_to(t0, (n, 3)).copy(), rotations=rot, local_translations=lt
    )
