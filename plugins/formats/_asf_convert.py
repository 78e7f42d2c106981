"""Any motion as an ASF skeleton and AMC-ready rotations (so AMC can be written from FBX,
glTF or BVH sources, with its ASF).

ASF describes bones, not joints: a bone starts where its parent bone ends, points along a
``direction`` for ``length`` units, and its dofs rotate it and everything below it. A
mocapflow joint ``j`` (BVH-like: its rotation turns its children's offsets) becomes the
bone ``j`` whose vector is the offset its children share; a child whose offset differs
(the hips' legs and spine, a chest's arms and neck) hangs below a dof-less helper bone
``<child>_offset`` spanning the difference, which leaves every joint where it was. The
root joint becomes the ASF ``root`` (``TX TY TZ RX RY RZ``); every bone gets dofs
``rx ry rz`` about axes aligned with the world (``axis 0 0 0 XYZ``), so the AMC values are
the joint's local rotation as extrinsic x, y, z angles. Units: ``length 0.45`` (CMU's:
0.0254 / 0.45 m per unit), ``angle deg``.

Joints keep their names (whitespace becomes ``_``; a joint named ``root`` other than the
root gets a suffix); the skeleton read back from the ASF has the extra helper joints and
the ``<bone>_end`` sites the ASF reader adds, so positions compare by joint name.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np

from mocapflow.framework import quaternions as quat
from mocapflow.framework.errors import DataError
from mocapflow.framework.motion import Motion

from ._asf import build_skeleton
from ._nodes import unique_names

LENGTH_UNIT = 0.45  # ASF ":units length": file values are inches * 0.45 (CMU)
SCALE = 0.0254 / LENGTH_UNIT  # metres per ASF unit
_SAME = 1e-9  # metres: children offsets this close share a bone


def _name(n: str) -> str:
    return re.sub(r"\s+", "_", n.strip()) or "joint"


def asf_motion(motion: Motion) -> Motion:
    """``motion`` on an ASF skeleton (module doc): the same joint positions; DataError for
    animated bone translations, which AMC cannot hold."""
    sk = motion.skeleton
    if sk.meta.get("format") == "asf" and sk.axes is not None and sk.channels:
        return motion
    if motion.local_translations is not None:
        lt = motion.local_translations
        if np.abs(lt - sk.offsets[None]).max(initial=0.0) > 1e-6:
            raise DataError(
                f"motion {motion.name!r}: its bones change length or translate over time, which AMC "
                "cannot hold (ASF bones have fixed lengths); write BVH, glTF or FBX instead"
            )
    nj = sk.n_joints
    base = ["root"] + [_name(n) for n in sk.names[1:]]
    helpers = {j: f"{base[j]}_offset" for j in range(1, nj)}
    names = unique_names(base + list(helpers.values()))
    bone = {j: names[j] for j in range(nj)}
    helper_name = {j: names[nj + k] for k, j in enumerate(range(1, nj))}
    kids: dict[int, list[int]] = {}
    for j in range(1, nj):
        kids.setdefault(int(sk.parents[j]), []).append(j)
    offsets = np.asarray(sk.offsets, dtype=float)
    vec = np.zeros((nj, 3))
    for j, cs in kids.items():
        if j == 0:
            continue  # the ASF root has no length
        groups: dict[int, int] = {}
        for c in cs:
            same = [d for d in cs if np.abs(offsets[d] - offsets[c]).max() <= _SAME]
            groups[c] = len(same)
        vec[j] = offsets[max(cs, key=lambda c: groups[c])]  # the offset most children share
    bones: list[dict[str, Any]] = []
    hierarchy: dict[str, list[str]] = {}

    def add_bone(name: str, v: np.ndarray, dof: list[str]) -> None:
        length = float(np.linalg.norm(v))
        direction = (v / length).tolist() if length > 0 else [0.0, 0.0, 1.0]
        bones.append(
            {
                "id": len(bones) + 1,
                "name": name,
                "direction": direction,
                "length": length / SCALE,
                "axis": [0.0, 0.0, 0.0],
                "axis_order": "XYZ",
                "dof": dof,
                "limits": [],
            }
        )

    for j in range(1, nj):
        add_bone(bone[j], vec[j], ["rx", "ry", "rz"])
    for j in range(nj):
        for c in kids.get(j, []):
            parent_name = "root" if j == 0 else bone[j]
            gap = offsets[c] - vec[j]
            if np.abs(gap).max() <= _SAME:
                hierarchy.setdefault(parent_name, []).append(bone[c])
            else:
                add_bone(helper_name[c], gap, [])
                hierarchy.setdefault(parent_name, []).append(helper_name[c])
                hierarchy.setdefault(helper_name[c], []).append(bone[c])
    asf = {
        "name": sk.name or motion.name or "mocapflow",
        "version": "1.10",
        "units": {"mass": 1.0, "length": LENGTH_UNIT, "angle": "deg"},
        "documentation": [f"converted by mocapflow from a {sk.meta.get('format', 'motion')} skeleton"],
        "root": {
            "order": ["TX", "TY", "TZ", "RX", "RY", "RZ"],
            "axis": "XYZ",
            "position": [0.0] * 3,
            "orientation": [0.0] * 3,
        },
        "bones": bones,
        "hierarchy": hierarchy,
    }
    new = build_skeleton(asf)
    src_of = {"root": 0, **{bone[j]: j for j in range(1, nj)}}
    n = motion.n_frames
    rot = np.broadcast_to(quat.identity(), (n, new.n_joints, 4)).copy()
    for k, name in enumerate(new.names):
        if name in src_of:
            rot[:, k] = motion.rotations[:, src_of[name]]
    return Motion(
        skeleton=new,
        root_translation=motion.root_translation,
        rotations=rot,
        fps=motion.fps,
        name=motion.name,
        metadata={k: v for k, v in motion.metadata.items() if k != "euler_branch"},
    )
