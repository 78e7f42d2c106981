"""Acclaim ASF skeleton files (CMU and HDM05 dialects): parsing, the mapping to the
generic joint model, and writing.

Mapping to :class:`~mocapflow.framework.skeleton.Skeleton`
----------------------------------------------------------
* One joint per ASF bone, placed at the **start** of the bone, plus the root, plus an
  end-site joint ``<bone>_end`` at the end of every leaf bone (``head_end`` is the top of
  the head). Joints are in depth-first order of the ``:hierarchy``.
* Rest frames of all joints are the world frame (the rest pose has identity rotations), so
  the offset of the joint of bone ``c`` from the joint of its parent bone ``b`` is
  ``direction_b * length_b`` in global rest coordinates (zero for the children of the
  root, which start at the root).
* The local rotation of bone ``b`` is ``C_b M_b C_b^-1``: ``C_b`` is the bone's ``axis``
  rotation and ``M_b`` the AMC Euler rotation, both applied about fixed axes in their
  listed order (``axis 0 0 20 XYZ``: x first; ``dof rx rz``: x first). The root uses its
  ``orientation``/``axis`` and the rotation channels of ``order``. This is the forward
  kinematics of the CMU viewer: ``R_b = R_parent C_b M_b C_b^-1``,
  ``end_b = start_b + R_b (direction_b * length_b)``.
* Lengths in metres: ``:units length L`` means file values are inches times ``L``
  (CMU and HDM05: 0.45), so metres = value * 0.0254 / L. Without a length unit, inches.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mocapflow.framework import quaternions as quat
from mocapflow.framework.errors import ParseError
from mocapflow.framework.joints import canonical_map
from mocapflow.framework.plugins import registered_joint_maps
from mocapflow.framework.quaternions import euler_extrinsic
from mocapflow.framework.skeleton import Skeleton

from ._common import MAX_DEGREES, MAX_METRES, check_text, read_bytes, split_ascii, strict_float, text_body, text_head

_ROOT_CHANNELS = {"TX", "TY", "TZ", "RX", "RY", "RZ"}
_DOFS = {"rx", "ry", "rz"}


def _floats(path: Path, line: int, words: list[str], n: int, what: str) -> list[float]:
    if len(words) < n:
        raise ParseError(path, line, f"expected {n} numbers for {what}, found {len(words)}")
    try:
        vals = [strict_float(w) for w in words[:n]]
    except ValueError:
        raise ParseError(path, line, f"expected {n} numbers for {what}, found {' '.join(words[:n])!r}") from None
    if not all(np.isfinite(vals)):
        raise ParseError(path, line, f"expected finite numbers for {what}, found {' '.join(words[:n])!r}")
    return vals


def _max_angle(asf: dict[str, Any]) -> float:
    return MAX_DEGREES if asf["units"]["angle"] == "deg" else float(np.deg2rad(MAX_DEGREES))


def _bound(path: Path, line: int, vals: list[float], limit: float, what: str, unit: str) -> None:
    """Reject physically absurd magnitudes (the bounds of ``_common``'s value policy)."""
    if max(abs(v) for v in vals) > limit:
        raise ParseError(
            path,
            line,
            f"expected {what} values within {limit:g} {unit} (10 km / 10^6 degrees), "
            f"found {' '.join(f'{v:g}' for v in vals)}",
        )


class _AsfState:
    """What the line handlers of :func:`parse_asf` share: the description built so far, the
    open bone block, and the names seen (for errors that name both lines)."""

    def __init__(self, path: Path, asf: dict[str, Any]) -> None:
        self.path, self.asf = path, asf
        self.bone: dict[str, Any] | None = None
        self.in_limits = False
        self.defined: set[str] = set()
        self.placed: dict[str, int] = {}
        self.name_line: dict[str, int] = {}
        self.parent_line: dict[str, int] = {}  # a :hierarchy parent -> its first line


_SECTIONS = {"units", "documentation", "root", "bonedata", "hierarchy", "name", "version"}


def parse_asf(path: str | Path) -> dict[str, Any]:
    """Parse an ASF file into a JSON-serialisable description (kept in ``Skeleton.meta``).

    Returns a dict with ``name``, ``version``, ``units`` (``length``, ``angle``, ``mass``),
    ``root`` (``order``, ``axis``, ``position``, ``orientation``), ``bones`` (list of dicts
    with ``name``, ``id``, ``direction``, ``length``, ``axis`` (3 angles), ``axis_order``,
    ``dof``, ``limits``) and ``hierarchy`` (parent -> list of children), all in file units.
    """
    path = Path(path)
    data = read_bytes(path, lambda head: text_head(path, head, (), "an ASF skeleton"))
    data = text_body(data)
    check_text(path, data)
    lines = data.decode("latin-1").replace("\r\n", "\n").split("\n")
    asf: dict[str, Any] = {
        "name": path.stem,
        "version": "",
        "units": {"length": None, "angle": "deg", "mass": None},
        "root": {
            "order": ["TX", "TY", "TZ", "RX", "RY", "RZ"],
            "axis": "XYZ",
            "position": [0.0] * 3,
            "orientation": [0.0] * 3,
        },
        "bones": [],
        "hierarchy": {},
        "documentation": [],
    }
    st = _AsfState(path, asf)
    section = ""
    seen_sections: set[str] = set()
    handlers = {"units": _units_line, "root": _root_line, "bonedata": _bone_line, "hierarchy": _hierarchy_line}
    for ln, raw in enumerate(lines, start=1):
        words = split_ascii(raw.split("#", 1)[0])
        if not words:
            continue
        if words[0].startswith(":"):
            section = words[0][1:].lower()
            seen_sections.add(section)
            st.in_limits = False
            if section == "name" and len(words) > 1:
                asf["asf_name"] = " ".join(words[1:])
            elif section == "version" and len(words) > 1:
                asf["version"] = words[1]
            elif section not in _SECTIONS:
                raise ParseError(path, ln, f"unknown ASF section {words[0]!r}")
        elif section == "documentation":
            asf["documentation"].append(raw.strip())
        elif section in handlers:
            handlers[section](st, ln, words, " ".join(words))
        else:
            raise ParseError(path, ln, f"expected an ASF section (':root', ':bonedata'...), found {' '.join(words)!r}")
    if st.bone is not None:
        raise ParseError(path, len(lines), "file ends inside a bone block (expected 'end')")
    if "bonedata" not in seen_sections or "hierarchy" not in seen_sections:
        raise ParseError(path, len(lines), "expected :bonedata and :hierarchy sections")
    known = {b["name"] for b in asf["bones"]} | {"root"}
    for parent, children in asf["hierarchy"].items():
        for n in [parent, *children]:
            if n not in known:
                line = st.placed.get(n) or st.parent_line.get(n) or _line_of_word(lines, n) or len(lines)
                raise ParseError(path, line, f"hierarchy names bone {n!r}, which :bonedata does not define")
    return asf


def _units_line(st: _AsfState, ln: int, words: list[str], text: str) -> None:
    k = words[0].lower()
    if k == "angle":
        unit = words[1].lower() if len(words) > 1 else ""
        if unit not in {"deg", "rad"}:
            raise ParseError(st.path, ln, f"expected 'angle deg' or 'angle rad', found {text!r}")
        st.asf["units"]["angle"] = unit
    elif k in {"length", "mass"}:
        st.asf["units"][k] = _floats(st.path, ln, words[1:], 1, k)[0]
        if k == "length" and st.asf["units"][k] <= 0:
            raise ParseError(st.path, ln, "expected a positive length unit")


def _root_line(st: _AsfState, ln: int, words: list[str], text: str) -> None:
    path, asf, k = st.path, st.asf, words[0].lower()
    if k == "order":
        order = [w.upper() for w in words[1:]]
        if not set(order) <= _ROOT_CHANNELS or len(set(order)) != len(order):
            raise ParseError(path, ln, f"expected root channels among TX TY TZ RX RY RZ, found {text!r}")
        asf["root"]["order"] = order
    elif k == "axis":
        ax = words[1].upper() if len(words) > 1 else ""
        if sorted(ax) != ["X", "Y", "Z"]:
            raise ParseError(path, ln, f"expected a root axis order such as XYZ, found {text!r}")
        asf["root"]["axis"] = ax
    elif k in {"position", "orientation"}:
        asf["root"][k] = _floats(path, ln, words[1:], 3, f"root {k}")
        if k == "position":
            _bound(path, ln, asf["root"][k], MAX_METRES / length_scale(asf), "root position", "file units")
        else:
            _bound(path, ln, asf["root"][k], _max_angle(asf), "root orientation", asf["units"]["angle"])


def _bone_line(st: _AsfState, ln: int, words: list[str], text: str) -> None:
    """One line of ``:bonedata``: ``begin``, ``end``, ``limits`` (and their continuation
    lines) or a bone field."""
    path, k = st.path, words[0].lower()
    if k == "begin":
        st.bone = {
            "id": None,
            "name": None,
            "direction": None,
            "length": None,
            "axis": [0.0] * 3,
            "axis_order": "XYZ",
            "dof": [],
            "limits": [],
            "line": ln,
        }
        st.in_limits = False
        return
    bone = st.bone
    if bone is None:
        raise ParseError(path, ln, f"expected 'begin' in :bonedata, found {text!r}")
    if k == "end":
        for field_ in ("name", "direction", "length"):
            if bone[field_] is None:
                raise ParseError(path, ln, f"bone starting at line {bone['line']} has no {field_}")
        del bone["line"]
        reach = [abs(d * bone["length"]) for d in bone["direction"]]
        limit = MAX_METRES / length_scale(st.asf)
        _bound(path, ln, reach, limit, f"bone {bone['name']!r} direction x length", "file units")
        st.asf["bones"].append(bone)
        st.bone = None
        return
    if k == "limits" or (st.in_limits and words[0].startswith("(")):
        st.in_limits = True
        nums = text[len("limits") :] if k == "limits" else text
        bone["limits"].append(nums.strip())
        return
    st.in_limits = False
    _bone_field(st, bone, ln, words, text)


def _bone_field(st: _AsfState, bone: dict[str, Any], ln: int, words: list[str], text: str) -> None:
    path, asf, k = st.path, st.asf, words[0].lower()
    if k == "id":
        bone["id"] = words[1] if len(words) > 1 else None
    elif k == "name":
        if len(words) < 2:
            raise ParseError(path, ln, "expected a bone name")
        if bone["name"] is not None:
            raise ParseError(path, ln, f"expected one name per bone block, found a second ({words[1]!r})")
        bone["name"] = words[1]
        if words[1] == "root" or words[1] in st.defined:
            first = f"line {st.name_line[words[1]]}" if words[1] in st.defined else "the root"
            raise ParseError(path, ln, f"bone name {words[1]!r} is already used by {first}; expected unique bone names")
        st.defined.add(words[1])
        st.name_line[words[1]] = ln
    elif k in {"direction", "length"}:
        vals = _floats(path, ln, words[1:], 3 if k == "direction" else 1, k)
        bone[k] = vals if k == "direction" else vals[0]
        _bound(path, ln, vals, MAX_METRES / length_scale(asf), k, "file units")
    elif k == "axis":
        bone["axis"] = _floats(path, ln, words[1:], 3, "axis")
        _bound(path, ln, bone["axis"], _max_angle(asf), "axis", asf["units"]["angle"])
        order = words[4].upper() if len(words) > 4 else "XYZ"
        if sorted(order) != ["X", "Y", "Z"]:
            raise ParseError(path, ln, f"expected an axis order such as XYZ, found {order!r}")
        bone["axis_order"] = order
    elif k == "dof":
        dof = [w.lower() for w in words[1:]]
        if not set(dof) <= _DOFS or len(set(dof)) != len(dof):
            raise ParseError(
                path,
                ln,
                f"expected rotational dofs among rx ry rz (translation and "
                f"length dofs are not supported), found {text!r}",
            )
        bone["dof"] = dof
    elif k not in {"bodymass", "cofmass"}:
        raise ParseError(path, ln, f"unknown bone field {words[0]!r}")


def _hierarchy_line(st: _AsfState, ln: int, words: list[str], text: str) -> None:
    if words[0].lower() in {"begin", "end"}:
        return
    for child in words[1:]:
        if child == "root":
            raise ParseError(st.path, ln, "expected bones as children in :hierarchy, found 'root' (it has no parent)")
        if child in st.placed:
            raise ParseError(
                st.path,
                ln,
                f"bone {child!r} already has a parent (line {st.placed[child]}); "
                "expected each bone once as a child in :hierarchy",
            )
        st.placed[child] = ln
    st.parent_line.setdefault(words[0], ln)
    st.asf["hierarchy"].setdefault(words[0], []).extend(words[1:])


def _line_of_word(lines: list[str], word: str) -> int | None:
    for ln in range(len(lines), 0, -1):
        if word in split_ascii(lines[ln - 1]):
            return ln
    return None


def length_scale(asf: dict[str, Any]) -> float:
    """Metres per ASF length unit (``:units length L``: file values are inches * L)."""
    unit = asf["units"]["length"]
    return 0.0254 / (unit if unit else 1.0)


def build_skeleton(asf: dict[str, Any]) -> Skeleton:
    """The generic skeleton of a parsed ASF (see the module docstring)."""
    degrees = asf["units"]["angle"] == "deg"
    scale = length_scale(asf)
    bones = {b["name"]: b for b in asf["bones"]}
    names: list[str] = ["root"]
    parents: list[int] = [-1]
    offsets: list[np.ndarray] = [np.zeros(3)]
    axes: list[np.ndarray] = [euler_extrinsic(asf["root"]["orientation"], asf["root"]["axis"].lower(), degrees)]
    orders: list[str] = ["".join(c[1].lower() for c in asf["root"]["order"] if c.startswith("R"))]
    channels: list[tuple[str, ...]] = [tuple(asf["root"]["order"])]
    bone_of: list[str | None] = [None]
    placed: set[str] = set()
    # depth-first over the hierarchy, children in listed order
    stack: list[tuple[str, int]] = [(c, 0) for c in reversed(asf["hierarchy"].get("root", []))]
    while stack:
        name, parent = stack.pop()
        if name in placed:
            raise ParseError(asf.get("path", asf["name"]), None, f"bone {name!r} appears twice in the hierarchy")
        placed.add(name)
        b = bones[name]
        j = len(names)
        names.append(name)
        parents.append(parent)
        pb = bone_of[parent]
        offsets.append(np.zeros(3) if pb is None else np.asarray(bones[pb]["direction"]) * bones[pb]["length"] * scale)
        axes.append(euler_extrinsic(b["axis"], b["axis_order"].lower(), degrees))
        orders.append("".join(d[1] for d in b["dof"]))
        channels.append(tuple(b["dof"]))
        bone_of.append(name)
        kids = asf["hierarchy"].get(name, [])
        if kids:
            stack.extend((c, j) for c in reversed(kids))
        else:
            names.append(f"{name}_end")
            parents.append(j)
            offsets.append(np.asarray(b["direction"]) * b["length"] * scale)
            axes.append(quat.identity())
            orders.append("")
            channels.append(())
            bone_of.append(None)
    meta = {k: v for k, v in asf.items() if k != "path"}
    meta["format"] = "asf"
    meta["length_scale"] = scale
    return Skeleton(
        names=tuple(names),
        parents=np.array(parents),
        offsets=np.array(offsets),
        canonical=canonical_map(names, "amc", registered_joint_maps()),
        rotation_orders=tuple(orders),
        axes=np.array(axes),
        channels=tuple(channels),
        name=asf["name"],
        meta=meta,
    )


def read_asf(path: str | Path) -> Skeleton:
    """Read an ASF skeleton file: joints at the start of each bone plus ``<bone>_end`` end
    sites, offsets in metres, ``axes`` the bones' ASF axis rotations, ``meta["bones"]`` etc.
    the file description for :func:`write_asf`; ``name`` is the file stem (CMU and HDM05 all
    say ``:name VICON``, kept as ``meta["asf_name"]``). ParseError names file and line."""
    asf = parse_asf(path)
    asf["path"] = str(path)
    return build_skeleton(asf)


def _fmt(x: float) -> str:
    return repr(float(x)) if x != int(x) or abs(x) >= 1e15 else str(int(x))


def write_asf(skeleton: Skeleton, path: str | Path) -> None:
    """Write an ASF file for a skeleton read by :func:`read_asf` (from ``skeleton.meta``;
    DataError for any other skeleton)."""
    from mocapflow.framework.errors import DataError

    meta = skeleton.meta
    if meta.get("format") != "asf" or "bones" not in meta:
        raise DataError(f"skeleton {skeleton.name!r} did not come from an ASF file; cannot write ASF")
    u = meta["units"]
    out = [
        "# ASF written by mocapflow",
        f":version {meta.get('version') or '1.10'}",
        f":name {meta.get('asf_name', skeleton.name)}",
        ":units",
    ]
    if u.get("mass") is not None:
        out.append(f"  mass {_fmt(u['mass'])}")
    if u.get("length") is not None:
        out.append(f"  length {_fmt(u['length'])}")
    out.append(f"  angle {u['angle']}")
    if meta.get("documentation"):
        out.append(":documentation")
        out += [f"   {d}" for d in meta["documentation"]]
    r = meta["root"]
    out += [
        ":root",
        f"   order {' '.join(r['order'])}",
        f"   axis {r['axis']}",
        f"   position {' '.join(_fmt(v) for v in r['position'])}",
        f"   orientation {' '.join(_fmt(v) for v in r['orientation'])}",
        ":bonedata",
    ]
    for i, b in enumerate(meta["bones"], start=1):
        out += [
            "  begin",
            f"     id {b.get('id') or i}",
            f"     name {b['name']}",
            f"     direction {' '.join(_fmt(v) for v in b['direction'])}",
            f"     length {_fmt(b['length'])}",
            f"     axis {' '.join(_fmt(v) for v in b['axis'])} {b['axis_order']}",
        ]
        if b["dof"]:
            out.append(f"    dof {' '.join(b['dof'])}")
            if b["limits"]:
                out.append(f"    limits {b['limits'][0]}")
                out += [f"           {lim}" for lim in b["limits"][1:]]
        out.append("  end")
    out += [":hierarchy", "  begin"]
    out += [f"    {p} {' '.join(c)}" for p, c in meta["hierarchy"].items()]
    out.append("  end")
    Path(path).write_text("\n".join(out) + "\n", encoding="latin-1")
