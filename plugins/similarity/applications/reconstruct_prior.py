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
* ``lengths`` float32 (C, P): each take's own bone lengths (stores written before it have
  none: :data:`REFERENCE_LENGTHS` stand in)
* ``clips.json``: ``joints``, ``fps``, and per take ``name``, ``subject``, ``source``, ``mirrored``

**Any skeleton** (:func:`pose_skeleton`): a skeleton's canonical map (its naming dialect)
is checked against its tree and completed by one rule (:func:`spine_map`): ``chest`` is
the spine joint where both arms branch off; ``lowerback`` a joint at the root's place,
``upperback`` the joint between root and chest nearest half the spine's arc length, ``neck``
the joint between chest and head nearest 0.37 of that arc (the places of the CMU/HDM05 ASF
rigs), each only where the dialect gave none or one off that chain. The pose joints are
then the canonical joints the skeleton has; a bone whose canonical parent is missing (a
spine of one or two bones, a skull without a neck) is composite: its direction in a prior
pose is that of the sum of the prior's bones it spans, each at the prior take's own length
(:meth:`PriorStore.on_joints`). Missing fingers, toes or head top are simply absent. The
control points (root, head, wrists, ankles) and the hips (heading) must exist.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, cast

import numpy as np

from mocapflow.framework import DataError, Index, Motion, Skeleton
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


#: Bone lengths (metres) of a median CMU/HDM05 performer, per :data:`POSE_JOINTS`: the
#: lengths a composite bone sums its prior bones with when a store holds no take lengths.
REFERENCE_LENGTHS: tuple[float, ...] = (
    0.0,  # root
    0.138, 0.405, 0.435, 0.13,  # lhip lknee lankle ltoes
    0.138, 0.405, 0.435, 0.13,  # rhip rknee rankle rtoes
    0.0, 0.122, 0.122, 0.124, 0.19, 0.097,  # lowerback upperback chest neck head headtop
    0.124, 0.2, 0.295, 0.19, 0.138,  # lclavicle lshoulder lelbow lwrist lfingers
    0.124, 0.2, 0.295, 0.19, 0.138,  # rclavicle rshoulder relbow rwrist rfingers
)  # fmt: skip

#: Joints every reconstructed skeleton needs: the 6 control points and the hips (heading).
CONTROL_JOINTS: tuple[str, ...] = ("root", "head", "lwrist", "rwrist", "lankle", "rankle", "lhip", "rhip")

#: Arc-length fractions of the spine rule (:func:`spine_map`): ``upperback`` along root ->
#: chest, ``neck`` along chest -> head (CMU ASF subject 01: 0.115/0.231 and 0.116/0.314 m).
SPINE_FRACTIONS: dict[str, float] = {"upperback": 0.5, "neck": 0.37}

_SPINE = ("lowerback", "upperback", "chest", "neck")


def _chain(parents: np.ndarray, j: int) -> list[int]:
    """Joint indices from the root down to ``j``."""
    out = [int(j)]
    while parents[out[-1]] >= 0:
        out.append(int(parents[out[-1]]))
    return out[::-1]


def spine_map(skeleton: Skeleton) -> dict[str, int]:
    """The skeleton's canonical map with the spine rule applied (module doc).

    Raises :class:`DataError` naming the control joints the skeleton lacks.
    """
    canon = dict(skeleton.canonical)
    missing = [j for j in CONTROL_JOINTS if j not in canon]
    if missing:
        raise DataError(
            f"skeleton {skeleton.name!r} has no joint for {missing}: reconstruction needs the control points "
            f"{list(CONTROL_JOINTS)} (its joints: {', '.join(skeleton.names[:40])})"
        )
    par = skeleton.parents
    path = _chain(par, canon["head"])
    if canon["root"] not in path:
        raise DataError(f"skeleton {skeleton.name!r}: its head does not hang below its root joint")
    path = path[path.index(canon["root"]) :]  # joints above the root (a floor joint) are no spine
    arms = set(_chain(par, canon["lwrist"])) & set(_chain(par, canon["rwrist"]))
    k_chest = max(k for k, j in enumerate(path) if j in arms)
    step = np.linalg.norm(skeleton.offsets[path], axis=1)
    step[0] = 0.0
    arc = np.cumsum(step)
    lo, hi = path[1:k_chest], path[k_chest + 1 : -1]
    given = {j: skeleton.canonical.get(j, -1) for j in _SPINE}
    out = {j: i for j, i in canon.items() if j not in _SPINE}
    if not 0 < k_chest < len(path) - 1:  # arms off the root or the head: no chest to speak of
        return out
    out["chest"] = path[k_chest]
    eps = 1e-3
    # keep the dialect's spine joints that lie on the chain in order; fill the rest by arc length
    if given["lowerback"] in lo:
        out["lowerback"] = given["lowerback"]
    else:
        at_root = [j for j in lo if arc[path.index(j)] < eps]
        if at_root:
            out["lowerback"] = at_root[0]
    lb = path.index(out["lowerback"]) if "lowerback" in out else 0
    if given["upperback"] in lo and path.index(given["upperback"]) > lb:
        out["upperback"] = given["upperback"]
    else:
        free = [j for j in lo if path.index(j) > lb and eps < arc[path.index(j)] < arc[k_chest] - eps]
        if free:
            f = SPINE_FRACTIONS["upperback"]
            out["upperback"] = min(free, key=lambda j: abs(arc[path.index(j)] / arc[k_chest] - f))
    if given["neck"] in hi:
        out["neck"] = given["neck"]
    else:
        span = arc[-1] - arc[k_chest]
        free = [j for j in hi if eps < arc[path.index(j)] - arc[k_chest] < span - eps]
        if free:
            f = SPINE_FRACTIONS["neck"]
            out["neck"] = min(free, key=lambda j: abs((arc[path.index(j)] - arc[k_chest]) / span - f))
    # a joint named twice (a dialect's upperback that is the branch point): the rule's name wins
    taken = {out[j]: j for j in _SPINE if j in out}
    return {j: i for j, i in out.items() if i not in taken or taken[i] == j}


def pose_skeleton(skeleton: Skeleton) -> tuple[Skeleton, tuple[str, ...]]:
    """The skeleton with the canonical map reconstruction uses (:func:`spine_map`) and its
    pose joints: the canonical joints it has, in :data:`POSE_JOINTS` order."""
    canon = spine_map(skeleton)
    joints = tuple(j for j in POSE_JOINTS if j in canon)
    return (skeleton if canon == skeleton.canonical else replace(skeleton, canonical=canon)), joints


def skeleton_view(store: PriorStore, skeleton: Skeleton) -> tuple[Skeleton, PriorStore, np.ndarray]:
    """What a reconstruction onto ``skeleton`` needs from ``store``: the skeleton with the
    spine rule's canonical map (:func:`pose_skeleton`; write the output on it), the store
    seen on its pose joints with its clavicles' places (:meth:`PriorStore.on_joints`), and
    its bone lengths (P,) from its rest pose; ``PosePrior.build(view, lengths, keep)``."""
    skeleton, joints = pose_skeleton(skeleton)
    joints = tuple(j for j in joints if j in (store.tree or store.joints))
    rest = Motion(skeleton, np.zeros((1, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (1, skeleton.n_joints, 1)), 30.0)
    pos = rest.canonical_positions(joints)
    return skeleton, store.on_joints(joints, pos[0]), bone_lengths(pos, joints)


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
    return cast("np.ndarray", np.median(length, axis=0))


def mirror_partners(joints: Sequence[str]) -> np.ndarray:
    """Index of each canonical joint's left/right counterpart (itself on the mid-line)."""
    j = list(joints)
    swap = {"l": "r", "r": "l"}
    return np.array(
        [j.index(swap[n[0]] + n[1:]) if n[0] in swap and swap[n[0]] + n[1:] in j else i for i, n in enumerate(j)]
    )


def mirror(local: np.ndarray, joints: Sequence[str]) -> np.ndarray:
    """Mirror image (x -> -x, left and right swapped) of heading-frame poses (T, P, 3)."""
    return cast("np.ndarray", local[:, mirror_partners(joints)] * np.array([-1.0, 1.0, 1.0]))


@dataclass
class PriorStore:
    """Bone-direction poses of the prior takes (see module doc).

    ``lengths`` (C, P): each take's bone lengths (None: :data:`REFERENCE_LENGTHS`);
    ``tree``: the joints of ``dirs`` when ``joints`` is a subset of them
    (:meth:`on_joints`; None: the same); ``rig``: rest positions (P, 3) of the skeleton the
    view serves (its clavicles' places on the chest).
    """

    joints: tuple[str, ...]
    fps: float
    dirs: np.ndarray
    clip_rows: np.ndarray
    clips: list[dict[str, Any]]
    lengths: np.ndarray | None = None
    tree: tuple[str, ...] | None = None
    rig: np.ndarray | None = None

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

    def on_joints(self, joints: Sequence[str], rest: np.ndarray | None = None) -> PriorStore:
        """The store seen on a subset of its joints (a skeleton's pose joints,
        :func:`pose_skeleton`): :meth:`retarget` gives those joints, a bone whose canonical
        parent is absent taking the direction of the prior bones it spans. With ``rest``
        (the skeleton's rest positions of ``joints``, (P, 3)) the clavicles start where that
        skeleton has them on its chest (:func:`chest_from_rig`)."""
        tree = self.tree or self.joints
        joints = tuple(joints)
        if joints == tree and rest is None:
            return replace(self, joints=tree, tree=None, rig=None)
        unknown = [j for j in joints if j not in tree]
        if unknown:
            raise DataError(f"pose joints {unknown} are not in the prior's joints {list(tree)}")
        bone_parents(joints)  # root first, parents first
        if rest is not None and np.shape(rest) != (len(joints), 3):
            raise DataError(f"rest positions must be ({len(joints)}, 3), got {np.shape(rest)}")
        return replace(self, joints=joints, tree=tree, rig=None if rest is None else np.asarray(rest, np.float64))

    def take_lengths(self, rows: np.ndarray | None = None) -> np.ndarray:
        """Bone lengths (n, P_tree) of the takes of ``rows`` (all: None)."""
        tree = self.tree or self.joints
        n = self.n_frames if rows is None else len(rows)
        if self.lengths is None:
            ref = dict(zip(POSE_JOINTS, REFERENCE_LENGTHS, strict=True))
            return np.broadcast_to(np.array([ref.get(j, 0.0) for j in tree], np.float32), (n, len(tree)))
        clip = np.repeat(np.arange(len(self.clips)), np.diff(self.clip_rows))
        return np.asarray(self.lengths, np.float32)[clip if rows is None else clip[rows]]

    def retarget(self, lengths: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """Poses (n, P, 3) float32 of ``rows`` (all: None) on a skeleton of bone ``lengths`` (P,)."""
        d = self.dirs if rows is None else self.dirs[rows]
        a = chain_matrix(bone_parents(self.joints)) * np.asarray(lengths, np.float64)[None, :]
        if self.tree is None:
            return cast(
                "np.ndarray", np.einsum("jb,nbc->njc", a.astype(np.float32), d, optimize=True).astype(np.float32)
            )
        # composite bones: the take's own pose on the full tree, then its vectors between the pose joints
        full = chain_matrix(bone_parents(self.tree)).astype(np.float32)
        own = np.einsum("jb,nbc->njc", full, d * self.take_lengths(rows)[..., None], optimize=True)
        idx = np.array([self.tree.index(j) for j in self.joints])
        v = own[:, idx] - own[:, idx[np.maximum(bone_parents(self.joints), 0)]]
        v[:, 0] = 0.0
        n = np.linalg.norm(v, axis=-1, keepdims=True)
        u = np.where(n > 1e-6, v / np.maximum(n, 1e-12), 0.0).astype(np.float32)
        # a bone the take's rig does not have (two joints at one place: CMU's lowerback at the
        # root, cgspeed's neck at the chest) points on along its first child's bone
        par = bone_parents(self.joints)
        for j in range(len(self.joints) - 1, 0, -1):
            kids = np.flatnonzero(par == j)
            if len(kids):
                gap = n[:, j, 0] <= 1e-6
                u[gap, j] = u[gap, kids[0]]
        if self.rig is not None:
            chest_from_rig(u, own, self.tree, self.joints, self.rig)
        return cast("np.ndarray", np.einsum("jb,nbc->njc", a.astype(np.float32), u, optimize=True).astype(np.float32))

    def select(self, keep: np.ndarray) -> PriorStore:
        """A store of the takes where ``keep`` (C,) is true (arrays copied)."""
        keep = np.asarray(keep, bool)
        rows = self.rows(keep)
        counts = np.diff(self.clip_rows)[keep]
        return replace(
            self,
            dirs=np.ascontiguousarray(self.dirs[rows]),
            clip_rows=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
            clips=[c for c, k in zip(self.clips, keep, strict=True) if k],
            lengths=None if self.lengths is None else np.asarray(self.lengths)[keep],
        )

    def save(self, folder: str | Path) -> Path:
        """Write the store (all its joints) into ``folder`` (atomically: a sibling temp folder renamed)."""
        folder = Path(folder)
        folder.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=folder.name + ".", dir=folder.parent))
        np.save(tmp / "dirs.npy", np.ascontiguousarray(self.dirs, np.float32))
        np.save(tmp / "clip_rows.npy", np.asarray(self.clip_rows, np.int64))
        if self.lengths is not None:
            np.save(tmp / "lengths.npy", np.asarray(self.lengths, np.float32))
        meta = {"joints": list(self.tree or self.joints), "fps": self.fps, "clips": self.clips}
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
        lengths = folder / "lengths.npy"
        return cls(
            tuple(meta["joints"]),
            float(meta["fps"]),
            np.load(folder / "dirs.npy", mmap_mode="r"),
            np.load(folder / "clip_rows.npy"),
            list(meta["clips"]),
            np.load(lengths) if lengths.is_file() else None,
        )


def chest_from_rig(
    u: np.ndarray, own: np.ndarray, tree: Sequence[str], joints: Sequence[str], rest: np.ndarray
) -> None:
    """Clavicle bone directions ``u`` (n, P, 3) of prior poses, in place, from where the
    served skeleton (``rest`` (P, 3)) starts its clavicles on its chest: their rest offsets
    in the chest's frame (up: to the neck, or the head; lateral: between the clavicles, or
    the shoulders where those coincide), put in each prior pose's chest frame (up: its
    chest -> neck bone; lateral: its shoulders, ``own`` (n, P_tree, 3)). Rigs differ there
    (CMU clavicles start at the neck's place, Bandai-Namco's a hand's width apart)."""
    j, t = list(joints), list(tree)
    up_child = "neck" if "neck" in j else "head"
    need = ("chest", "lclavicle", "rclavicle", "lshoulder", "rshoulder", up_child)
    if any(n not in j for n in need) or any(n not in t for n in ("lshoulder", "rshoulder")):
        return
    par = bone_parents(j)
    c = j.index("chest")
    if par[j.index("lclavicle")] != c or par[j.index("rclavicle")] != c or par[j.index(up_child)] != c:
        return

    def frame(up: np.ndarray, lat: np.ndarray) -> np.ndarray:
        up = up / np.maximum(np.linalg.norm(up, axis=-1, keepdims=True), 1e-12)
        lat = lat - (lat * up).sum(-1, keepdims=True) * up
        lat = lat / np.maximum(np.linalg.norm(lat, axis=-1, keepdims=True), 1e-12)
        return np.stack([lat, up, np.cross(lat, up)], -2)  # rows: lateral, up, forward

    rest = np.asarray(rest, np.float64)
    lat_r = rest[j.index("lclavicle")] - rest[j.index("rclavicle")]
    if np.linalg.norm(lat_r) < 0.01:
        lat_r = rest[j.index("lshoulder")] - rest[j.index("rshoulder")]
    rig = frame(rest[j.index(up_child)] - rest[c], lat_r)
    if np.linalg.norm(rest[j.index(up_child)] - rest[c]) < 1e-6 or np.linalg.norm(lat_r) < 1e-6:
        return
    prior = frame(
        u[:, j.index(up_child)].astype(np.float64), own[:, t.index("lshoulder")] - own[:, t.index("rshoulder")]
    )
    for side in ("lclavicle", "rclavicle"):
        off = rig @ (rest[j.index(side)] - rest[c])
        if np.linalg.norm(off) < 1e-6:
            continue
        v = np.einsum("k,nkc->nc", off, prior)
        u[:, j.index(side)] = v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def build_store(
    motions: Iterable[Motion],
    fps: float = 30.0,
    joints: Sequence[str] = POSE_JOINTS,
    mirrored: bool = True,
) -> PriorStore:
    """A :class:`PriorStore` of ``motions`` (resampled to ``fps``), each with its mirror image
    and its bone lengths.

    Every skeleton is read through the spine rule (:func:`spine_map`). Takes lacking a pose
    joint (Bandai-Namco and PyMO BVH: spine joints; measured, placing them by the rule does
    not help: docs/knn.md) or the control joints are skipped (they are not in ``clips``).
    """
    from mocapflow.framework.normalize import resample

    joints = tuple(joints)
    parents = bone_parents(joints)
    dirs, clips, lengths = [], [], []
    for m in motions:
        if m.n_frames < 2:
            continue
        try:
            skel, _ = pose_skeleton(m.skeleton)
        except DataError:
            continue
        if any(j not in skel.canonical for j in joints):
            continue
        if abs(m.fps - fps) > 1e-6:
            m = resample(m, fps)
        local = local_positions(m.with_arrays(skeleton=skel).canonical_positions(joints), joints)
        own = np.median(directions(local, parents)[1], axis=0)
        for flip in (False, True) if mirrored else (False,):
            d, _ = directions(mirror(local, joints) if flip else local, parents)
            dirs.append(d.astype(np.float32))
            lengths.append((own[mirror_partners(joints)] if flip else own).astype(np.float32))
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
    return PriorStore(joints, float(fps), np.concatenate(dirs), rows, clips, np.stack(lengths))


def prior_index() -> Index:
    """The kNN index of a prior database: an exact kd-tree, one thread."""
    from ..knn.kdtree import KDTreeIndex

    return KDTreeIndex(workers=1)
