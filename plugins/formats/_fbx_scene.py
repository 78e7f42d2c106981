"""The FBX scene document under :mod:`.fbx`: ``Properties70`` with the file's templates as
defaults, ``GlobalSettings`` axes, objects and connections, the take (``AnimationStack``), its
time span and the KTime tick rate. No animation is evaluated here."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mocapflow.framework import quaternions as quat
from mocapflow.framework.errors import ParseError

from ._fbx_parse import Node

KTIME_V7 = 46_186_158_000
KTIME_V8 = 141_120_000
#: Largest |value| of a transform property or key (file units up to millimetres, degrees):
#: above any real scene, below the overflow of the products that follow.
MAX_VALUE = 1.0e9


def props70(node: Node | None) -> dict[str, list[Any]]:
    out: dict[str, list[Any]] = {}
    p70 = node.find("Properties70") if node is not None else None
    for p in p70.children if p70 is not None else []:
        if p.name == "P" and p.props and isinstance(p.props[0], str):
            out[p.props[0]] = p.props[4:]
    return out


class Props:
    """A model's properties with the file's template as defaults."""

    def __init__(self, path: Path, own: dict[str, Any], template: dict[str, Any], what: str) -> None:
        self.path, self.own, self.template, self.what = path, own, template, what

    def get(self, key: str, default: Any) -> Any:
        v = self.own.get(key, self.template.get(key))
        return default if v is None else v

    def vec(self, key: str, default: tuple[float, float, float]) -> np.ndarray:
        v = self.get(key, default)
        try:
            arr = np.array([float(x) for x in v[:3]], dtype=float)
        except (TypeError, ValueError):
            arr = np.zeros(0)
        if arr.shape != (3,) or not np.all(np.abs(arr) <= MAX_VALUE):
            raise ParseError(
                self.path,
                None,
                f"{self.what}: expected three numbers within {MAX_VALUE:g} in {key!r}, found {v!r}"[:200],
            )
        return arr

    def num(self, key: str, default: float) -> float:
        v = self.get(key, [default])
        if not v or isinstance(v[0], (str, bytes)) or not np.isfinite(float(v[0])):
            raise ParseError(self.path, None, f"{self.what}: expected a number in {key!r}, found {v!r}"[:200])
        return float(v[0])


def file_axes(path: Path, gs: Props) -> np.ndarray:
    """Rotation (quaternion) from the file's axes to y-up, front along -z."""
    up = int(gs.num("UpAxis", 1)), int(np.sign(gs.num("UpAxisSign", 1)) or 1)
    front = int(gs.num("FrontAxis", 2)), int(np.sign(gs.num("FrontAxisSign", 1)) or 1)
    coord = int(gs.num("CoordAxis", 0)), int(np.sign(gs.num("CoordAxisSign", 1)) or 1)
    eye = np.eye(3)
    if not all(0 <= a <= 2 for a, _ in (up, front, coord)):
        raise ParseError(path, None, f"GlobalSettings: expected axes 0-2, found up {up}, front {front}, coord {coord}")
    u, f, c = eye[up[0]] * up[1], -eye[front[0]] * front[1], eye[coord[0]] * coord[1]
    if not np.allclose(np.cross(f, u), c):  # not right-handed: Blender's fallback, z up and y forward
        u, f, c = eye[2], eye[1], eye[0]
    return quat.from_matrix(np.stack([c, u, -f]))


def take_stack(
    path: Path, objects: dict[int, tuple[str, str, Node]], animation: int | str
) -> tuple[int, str, list[str]]:
    stacks = [(oid, name) for oid, (kind, name, _n) in objects.items() if kind == "AnimationStack"]
    names = [n for _, n in stacks]
    if not stacks:
        raise ParseError(path, None, "expected an AnimationStack (a take), found none")
    if isinstance(animation, str):
        if animation not in names:
            raise ParseError(path, None, f"expected an animation named {animation!r}, found {names}")
        k = names.index(animation)
    elif not 0 <= animation < len(stacks):
        raise ParseError(path, None, f"expected an animation index below {len(stacks)}, found {animation}")
    else:
        k = animation
    return stacks[k][0], names[k], names


EMPTY = Node("", [], [], 0)
#: The kinds of ``Objects`` children the reader uses (others are skipped unparsed: meshes,
#: materials, embedded media).
OBJECT_KINDS = frozenset({"Model", "AnimationStack", "AnimationLayer", "AnimationCurveNode", "AnimationCurve"})


def scene(
    path: Path, root: Node
) -> tuple[dict[str, Any], dict[int, tuple[str, str, Node]], dict[int, int], dict[int, list[tuple[int, str]]]]:
    """The Model property template, objects by id (kind, name, node), model parents and
    connections by parent id."""
    template: dict[str, Any] = {}
    for ot in (root.find("Definitions") or EMPTY).find_all("ObjectType"):
        if ot.props[:1] == ["Model"]:
            for pt in ot.find_all("PropertyTemplate"):
                template.update(props70(pt))
    objects: dict[int, tuple[str, str, Node]] = {}
    for o in (root.find("Objects") or EMPTY).children:
        if len(o.props) >= 2 and isinstance(o.props[0], int) and isinstance(o.props[1], str):
            objects[o.props[0]] = (o.name, o.props[1].split("\x00\x01")[0], o)
    parent: dict[int, int] = {}
    owner: dict[int, list[tuple[int, str]]] = {}  # parent id -> [(child id, property)]
    for c in (root.find("Connections") or EMPTY).find_all("C"):
        if len(c.props) < 3 or not all(isinstance(x, int) for x in c.props[1:3]):
            raise ParseError(path, None, f"Connections: expected 'C' records with two ids, found {c.props[:3]!r}"[:200])
        kind, child, par = c.props[0], c.props[1], c.props[2]
        prop = c.props[3] if len(c.props) > 3 and isinstance(c.props[3], str) else ""
        owner.setdefault(par, []).append((child, prop))
        if kind == "OO" and objects.get(child, ("",))[0] == "Model" and objects.get(par, ("",))[0] == "Model":
            if child in parent:
                raise ParseError(path, None, f"model {objects[child][1]!r} has two parents; expected a tree")
            parent[child] = par
    return template, objects, parent, owner


def templates(root: Node, kind: str) -> dict[str, Any]:
    """The property template of an object type (``Definitions``)."""
    out: dict[str, Any] = {}
    for ot in (root.find("Definitions") or EMPTY).find_all("ObjectType"):
        if ot.props[:1] == [kind]:
            for pt in ot.find_all("PropertyTemplate"):
                out.update(props70(pt))
    return out


def take_span(stack: Node, template: dict[str, Any]) -> tuple[int, int] | None:
    """The take's time span in ticks: ``LocalStart``/``LocalStop``, else
    ``ReferenceStart``/``ReferenceStop`` (as the FBX SDK and ufbx read it); None without
    them or when they are not a forward span."""
    own = props70(stack)
    for a, b in (("LocalStart", "LocalStop"), ("ReferenceStart", "ReferenceStop")):
        va, vb = own.get(a, template.get(a)), own.get(b, template.get(b))
        if va and vb and isinstance(va[0], int) and isinstance(vb[0], int):
            return (va[0], vb[0]) if vb[0] >= va[0] else None
    return None


def ktime(root: Node, version: int) -> int:
    ktps = KTIME_V8 if version >= 8000 else KTIME_V7
    head = root.find("FBXHeaderExtension")
    hv = head.find("FBXHeaderVersion") if head is not None else None
    flags = head.find("OtherFlags") if head is not None else None
    tcd = flags.find("TCDefinition") if flags is not None else None
    if (
        hv is not None
        and hv.props
        and isinstance(hv.props[0], int)
        and hv.props[0] >= 1004
        and tcd is not None
        and tcd.props
    ):
        ktps = {0: KTIME_V8, 127: KTIME_V7}.get(tcd.props[0], KTIME_V8)
    return ktps
