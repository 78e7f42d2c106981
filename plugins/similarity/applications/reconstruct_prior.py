"""The reconstruction's prior database: every take as bone directions, retargeted on demand.

A prior pose is stored skeleton-free: for every canonical joint (but the root) the unit
vector from its canonical parent (the nearest canonical ancestor present), in the root's
heading frame (root at the origin, facing +z). Multiplying by the bone lengths of *a*
skeleton and summing down the tree gives that pose on that skeleton
(:meth:`PriorStore.retarget`), so takes of CMU, HDM05 and BVH performers of any size
serve the performer being reconstructed with the performer's own proportions. Each take
is stored with its left/right mirror image; all are resampled to one rate (``fps``).

The store is a folder of ``.npy`` arrays (read memory-mapped) plus ``clips.json``:

* ``dirs`` float32 (N, P, 3): bone directions (row 0, the root, is zero)
* ``clip_rows`` int64 (C + 1,): take ``c`` holds rows ``clip_rows[c]:clip_rows[c+1]``
* ``clips.json``: ``joints``, ``fps``, and per take ``name``, ``subject``, ``source``, ``mirrored``
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapflow.framework import DataError, Motion
from mocapflow.framework.joints import CANONICAL_JOINTS
from mocapflow.framework.normalize import facing_angles, rotate_about_y

#: Canonical joint -> its parent in the canonical body tree.
CANONICAL_PARENT: dict[str, str] = {
    "lhip": "root",
    "lknee": "lhip",
    "lankle": "lknee",
    "ltoes": "lankle",
    "rhip": "root",
    "rknee": "rhip",
    "rankle": "rknee",
    "rtoes": "rankle",
    "lowerback": "root",
    "upperback": "lowerback",
    "chest": "upperback",
    "neck": "chest",
    "head": "neck",
    "headtop": "head",
    "lclavicle": "chest",
    "lshoulder": "lclavicle",
    "lelbow": "lshoulder",
    "lwrist": "lelbow",
    "lfingers": "lwrist",
    "rclavicle": "chest",
    "rshoulder": "rclavicle",
    "relbow": "rshoulder",
    "rwrist": "relbow",
    "rfingers": "rwrist",
}

#: Canonical joints of the pose: every canonical joint, so that every bone is rigid (ASF:
#: CMU, HDM05; the cgspeed and Xia BVH sets; Bandai-Namco and PyMO lack a spine joint).
POSE_JOINTS: tuple[str, ...] = CANONICAL_JOINTS


def bone_parents(joints: Sequence[str]) -> np.ndarray:
    """Index (P,) of each joint's nearest canonical ancestor within ``joints`` (-1: root)."""
    j = list(joints)
    if not j or j[0] != "root":
        raise DataError(f"pose joints must start with 'root', got {j[:3]}")
    out = np.full(len(j), -1)
    for i, name in enumerate(j[1:], 1):
        p = CANONICAL_PARENT[name]
        while p not in j:
            p = CANONICAL_PARENT[p]
        out[i] = j.index(p)
        if out[i] >= i:
            raise DataError(f"pose joints must list parents first: {name} before {p}")
    return out


def chain_matrix(parents: np.ndarray) -> np.ndarray:
    """A (P, P): ``A[j, b] = 1`` if bone ``b`` (joint b and its parent) lies between the root and ``j``."""
    n = len(parents)
    a = np.zeros((n, n))
    for j in range(1, n):
        b = j
        while b > 0:
            a[j, b] = 1.0
            b = parents[b]
    return a


def local_positions(positions: np.ndarray, joints: Sequence[str]) -> np.ndarray:
    """World positions (T, P, 3) -> root at the origin, heading (from the hips) turned to +z."""
    j = list(joints)
    centred = positions - positions[:, j.index("root")][:, None, :]
    return rotate_about_y(centred, -facing_angles(positions, j))


def directions(local: np.ndarray, parents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit bone vectors (T, P, 3) (zero for the root and zero-length bones) and lengths (T, P)."""
    v = local - local[:, np.maximum(parents, 0)]
    v[:, 0] = 0.0
    length = np.linalg.norm(v, axis=-1)
    return np.where(length[..., None] > 1e-6, v / np.maximum(length, 1e-12)[..., None], 0.0), length


def bone_lengths(positions: np.ndarray, joints: Sequence[str]) -> np.ndarray:
    """A skeleton's bone lengths (P,) metres: the median over frames of each joint's distance
    to its canonical parent (constant for rigid chains; the median for chains that bend)."""
    _, length = directions(np.asarray(positions, np.float64), bone_parents(joints))
    return np.median(length, axis=0)


def mirror_partners(joints: Sequence[str]) -> np.ndarray:
    """Index of each canonical joint's left/right counterpart (itself on the mid-line)."""
    j = list(joints)
    swap = {"l": "r", "r": "l"}
    return np.array(
        [j.index(swap[n[0]] + n[1:]) if n[0] in swap and swap[n[0]] + n[1:] in j else i for i, n in enumerate(j)]
    )


def mirror(local: np.ndarray, joints: Sequence[str]) -> np.ndarray:
    """Mirror image (x -> -x, left and right swapped) of heading-frame poses (T, P, 3)."""
    return local[:, mirror_partners(joints)] * np.array([-1.0, 1.0, 1.0])


@dataclass
class PriorStore:
    """Bone-direction poses of the prior takes (see module doc)."""

    joints: tuple[str, ...]
    fps: float
    dirs: np.ndarray
    clip_rows: np.ndarray
    clips: list[dict]

    @property
    def n_frames(self) -> int:
        return int(len(self.dirs))

    def rows(self, keep: np.ndarray) -> np.ndarray:
        """Row indices of the takes where ``keep`` (C,) is true."""
        c = np.flatnonzero(keep)
        return (
            np.concatenate([np.arange(self.clip_rows[i], self.clip_rows[i + 1]) for i in c])
            if len(c)
            else np.zeros(0, int)
        )

    def retarget(self, lengths: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """Poses (n, P, 3) float32 of ``rows`` (all: None) on a skeleton of bone ``lengths`` (P,)."""
        a = chain_matrix(bone_parents(self.joints)) * np.asarray(lengths, np.float64)[None, :]
        d = self.dirs if rows is None else self.dirs[rows]
        return np.einsum("jb,nbc->njc", a.astype(np.float32), d, optimize=True).astype(np.float32)

    def save(self, folder: str | Path) -> Path:
        """Write the store into ``folder`` (atomically: a sibling temp folder renamed)."""
        folder = Path(folder)
        folder.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=folder.name + ".", dir=folder.parent))
        np.save(tmp / "dirs.npy", np.ascontiguousarray(self.dirs, np.float32))
        np.save(tmp / "clip_rows.npy", np.asarray(self.clip_rows, np.int64))
        meta = {"joints": list(self.joints), "fps": self.fps, "clips": self.clips}
        (tmp / "clips.json").write_text(json.dumps(meta, indent=1))
        if folder.exists():
            for f in folder.iterdir():
                f.unlink()
            folder.rmdir()
        os.replace(tmp, folder)
        return folder

    @classmethod
    def load(cls, folder: str | Path) -> PriorStore:
        """Open a saved store; the pose arrays are memory-mapped, not read."""
        folder = Path(folder)
        meta_file = folder / "clips.json"
        if not meta_file.is_file():
            raise DataError(f"{folder}: not a reconstruction prior (no clips.json); build one with build_store")
        meta = json.loads(meta_file.read_text())
        return cls(
            tuple(meta["joints"]),
            float(meta["fps"]),
            np.load(folder / "dirs.npy", mmap_mode="r"),
            np.load(folder / "clip_rows.npy"),
            list(meta["clips"]),
        )


def build_store(
    motions: Iterable[Motion], fps: float = 30.0, joints: Sequence[str] = POSE_JOINTS, mirrored: bool = True
) -> PriorStore:
    """A :class:`PriorStore` of ``motions`` (resampled to ``fps``), each with its mirror image.

    Takes lacking a pose joint are skipped (listed in ``skipped`` of the first clip entry's
    store metadata is not kept: they are simply not in ``clips``).
    """
    from mocapflow.framework.normalize import resample

    joints = tuple(joints)
    parents = bone_parents(joints)
    dirs, clips = [], []
    for m in motions:
        if any(j not in m.skeleton.canonical for j in joints) or m.n_frames < 2:
            continue
        if abs(m.fps - fps) > 1e-6:
            m = resample(m, fps)
        local = local_positions(m.canonical_positions(joints), joints)
        for flip in (False, True) if mirrored else (False,):
            d, _ = directions(mirror(local, joints) if flip else local, parents)
            dirs.append(d.astype(np.float32))
            clips.append(
                {
                    "name": m.name,
                    "subject": str(m.metadata.get("subject", "")),
                    "source": str(m.metadata.get("source", m.metadata.get("format", ""))),
                    "mirrored": flip,
                }
            )
    if not clips:
        raise DataError(f"no prior take has every pose joint {list(joints)}")
    rows = np.cumsum([0] + [len(d) for d in dirs])
    return PriorStore(joints, float(fps), np.concatenate(dirs), rows, clips)
