"""Biovision BVH motion files: reader and writer.

* Any channel order and count per joint: 3 rotation channels, 6 channels (position +
  rotation) on the root or on any joint, in any order. Rotations are intrinsic in the
  listed order (``Zrotation Xrotation Yrotation``: ``R = Rz Rx Ry``).
* ``End Site`` blocks become joints named ``<parent>_end`` (``Head_end`` is the top of
  the head); a second end site of the same parent gets ``_end2``...
* Root translation: the root's position channels (absolute positions, as most tools
  read them); a root without position channels stays at its ``OFFSET``.
* Position channels on other joints (Bandai-Namco has 6 channels everywhere): when they
  are constant and equal to the joint's ``OFFSET`` (within 1e-4 file units) they carry
  nothing and ``Motion.local_translations`` stays ``None``; otherwise it holds them.
* Units: BVH has none. ``scale="auto"`` takes the skeleton's span ``s`` (the longest path
  between two joints along the bones, summing bone lengths: fingertip to toe, in file
  units; :func:`skeleton_span`) and picks the unit among metres, centimetres, millimetres,
  inches and CMU ASF units (inches * 0.45, the cgspeed CMU conversions) whose implied span
  ``s * unit`` is closest to :data:`TYPICAL_SPAN_M` on a log scale. The span depends on the
  bone lengths only, not on the rest pose the OFFSETs describe (T-pose, A-pose, a clip's
  first frame), so every clip of one character gets the same unit (the rest pose's height
  did not: sibling clips came out 2.17 m and 1.15 m tall). The chosen scale (metres per
  file unit), unit name, ``unit_source`` and span are recorded in the clip's metadata;
  pass a float or a unit name (``"cm"``, ``"inch"``...) to force it.
* A static root above the real hips (Bandai-Namco: ``joint_Root`` never moves, ``Hips``
  has position channels) is dropped by default (``collapse_static_root``): the hips become
  the root, so ``root_translation`` and ``rotations[:, 0]`` carry the body's motion as
  normalisation and features expect. ``metadata["collapsed_root"]`` names the dropped
  joint; world positions are unchanged. The skeleton's ``meta["collapsed_root"]`` keeps
  the dropped joint (name, offset, channels, its constant rotation and translation in
  file units), and the writer puts it back: a rig that binds by name gets its own root.
* ``Frame Time`` gives fps (``metadata["frame_time"]`` keeps the exact value).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import Field

from mocapflow.framework import quaternions as quat
from mocapflow.framework.components import Format
from mocapflow.framework.components import Params as BaseParams
from mocapflow.framework.errors import DataError, ParseError
from mocapflow.framework.joints import canonical_map
from mocapflow.framework.motion import Motion
from mocapflow.framework.plugins import registered_joint_maps
from mocapflow.framework.skeleton import Skeleton

from . import _euler_branch as euler_branch
from ._bvh_table import _check_bounds, _check_motion, _rotations
from ._bvh_write import write_bvh
from ._common import (
    MAX_FPS,
    line_of,
    strict_float,
    strict_int,
    text_head,
)
from ._stream import TextBlocks

__all__ = ["BvhFormat", "read_bvh", "write_bvh", "BVH_UNITS"]

#: Candidate units of ``scale="auto"``: name -> metres per file unit.
BVH_UNITS: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001, "inch": 0.0254, "asf_cmu": 0.0254 / 0.45}
#: Typical :func:`skeleton_span` of a person used by ``scale="auto"``, metres: the corpus's
#: 32 BVH files span 1.97-2.38 m in their units (docs/formats.md).
TYPICAL_SPAN_M = 2.2
_CHANNELS = {"xposition", "yposition", "zposition", "xrotation", "yrotation", "zrotation"}
_MOTION_RE = re.compile(rb"^[ \t]*MOTION[ \t]*\r?$", re.MULTILINE)


class _Joint:
    __slots__ = ("name", "parent", "offset", "channels", "line", "offset_line", "channels_line")

    def __init__(self, name: str | None, parent: int, line: int) -> None:
        self.name, self.parent, self.line = name, parent, line  # name None: an End Site, named at the end
        self.offset: list[float] | None = None
        self.offset_line = line
        self.channels_line = 0
        self.channels: list[str] = []


def _keyword(word: str) -> str:
    """``word`` upper-cased when it is written in one case (``CHANNELS``, ``channels``) or
    capitalised (``Channels``, ``End Site``), as exporters write keywords; a mixed case such
    as ``CHANnELS`` is no keyword (an error where one is expected)."""
    return word.upper() if word in (word.upper(), word.lower(), word.capitalize()) else ""


def _parse_hierarchy(path: Path, text: bytes) -> list[_Joint]:
    # split on ASCII whitespace only, as the tokenizer of the motion section (str.split also
    # splits on NBSP and NEL, so it serves only files without them)
    lines: list[Any] = text.decode("latin-1").split("\n")
    if b"\xa0" in text or b"\x85" in text:
        lines = [[w.decode("latin-1") for w in ln.split()] for ln in text.split(b"\n")]
    words: list[tuple[str, int]] = [
        (w, ln) for ln, line in enumerate(lines, start=1) for w in (line if isinstance(line, list) else line.split())
    ]
    if not words or _keyword(words[0][0]) != "HIERARCHY":
        raise ParseError(path, words[0][1] if words else 1, "expected 'HIERARCHY' at the start of a BVH file")
    return _Hierarchy(path, words).parse()


class _Hierarchy:
    """The word-by-word parser of a BVH hierarchy (after ``HIERARCHY``, up to ``MOTION``)."""

    def __init__(self, path: Path, words: list[tuple[str, int]]) -> None:
        self.path, self.words, self.n = path, words, len(words)
        self.joints: list[_Joint] = []
        self.names: dict[str, int] = {}  # joint name -> line
        self.stack: list[int] = []
        self.i = 1
        self.last = words[-1][1]

    def take(self, k: int, what: str) -> list[tuple[str, int]]:
        if self.i + k > self.n:
            raise ParseError(self.path, self.last, f"file ends inside the hierarchy, expected {what}")
        return self.words[self.i : self.i + k]

    def parse(self) -> list[_Joint]:
        path, words = self.path, self.words
        while self.i < self.n:
            w, ln = words[self.i]
            key = _keyword(w)
            if key in ("ROOT", "JOINT") or (
                key == "END" and self.i + 1 < self.n and _keyword(words[self.i + 1][0]) == "SITE"
            ):
                self.joint(w, key, ln)
            elif key == "OFFSET":
                self.offset(ln)
            elif key == "CHANNELS":
                self.channels(ln)
            elif w == "}":
                self.close(ln)
            else:
                raise ParseError(path, ln, f"expected ROOT, JOINT, End Site, OFFSET, CHANNELS or '}}', found {w!r}")
        if self.stack:
            name = self.joints[self.stack[-1]].name
            raise ParseError(path, self.last, f"expected '}}' closing {name!r} before MOTION")
        if not self.joints:
            raise ParseError(path, self.last, "expected a ROOT joint")
        for j in self.joints:  # End Sites: <parent>_end, _end2... never a name the file uses
            if j.name is None:
                parent, k = self.joints[j.parent].name, 2
                name = f"{parent}_end"
                while name in self.names:
                    name = f"{parent}_end{k}"
                    k += 1
                j.name = name
                self.names[name] = j.line
        return self.joints

    def joint(self, w: str, key: str, ln: int) -> None:
        path, joints, stack = self.path, self.joints, self.stack
        if key == "ROOT" and (stack or joints):
            raise ParseError(path, ln, "only one ROOT is supported")
        if key != "ROOT" and not stack:
            raise ParseError(path, ln, f"expected ROOT, found {w!r}")
        if stack and joints[stack[-1]].name is None:
            raise ParseError(path, ln, f"expected only OFFSET and '}}' inside an End Site, found {w!r}")
        name = None
        if key != "END":
            ((name, _l),) = self.take(2, "a joint name")[1:]
            if name in self.names:
                raise ParseError(
                    path,
                    ln,
                    f"joint name {name!r} is already used at line {self.names[name]}; expected unique joint names",
                )
            self.names[name] = ln
        self.i += 2
        joints.append(_Joint(name, stack[-1] if stack else -1, ln))
        brace, bl = self.take(1, "'{'")[0]
        if brace != "{":
            what = "End Site" if name is None else repr(name)
            raise ParseError(path, bl, f"expected '{{' after {what}, found {brace!r}")
        self.i += 1
        stack.append(len(joints) - 1)

    def offset(self, ln: int) -> None:
        if not self.stack:
            raise ParseError(self.path, ln, "OFFSET outside a joint")
        vals = self.take(4, "three OFFSET values")[1:]
        j = self.joints[self.stack[-1]]
        if j.offset is not None:
            raise ParseError(
                self.path,
                ln,
                f"expected one OFFSET per joint, found a second (the first is at line {j.offset_line})",
            )
        j.offset_line = ln
        try:
            j.offset = [strict_float(v) for v, _ in vals]
        except ValueError:
            raise ParseError(
                self.path, ln, f"expected three numbers after OFFSET, found {' '.join(v for v, _ in vals)!r}"
            ) from None
        if not np.all(np.isfinite(j.offset)):
            raise ParseError(self.path, ln, "expected finite OFFSET values")
        self.i += 4

    def channels(self, ln: int) -> None:
        path = self.path
        if not self.stack:
            raise ParseError(path, ln, "CHANNELS outside a joint")
        j = self.joints[self.stack[-1]]
        if j.name is None:
            raise ParseError(path, ln, "expected only OFFSET and '}' inside an End Site, found CHANNELS")
        if j.channels_line:
            raise ParseError(
                path,
                ln,
                f"expected one CHANNELS line per joint, found a second (the first is at line {j.channels_line})",
            )
        j.channels_line = ln
        cnt_w = self.take(2, "a channel count")[1][0]
        try:
            cnt = strict_int(cnt_w)
        except ValueError:
            raise ParseError(path, ln, f"expected a channel count after CHANNELS, found {cnt_w!r}") from None
        if cnt > 6:
            raise ParseError(path, ln, f"expected at most 6 channels per joint, found {cnt}")
        self.i += 2
        chans = [c for c, _ in self.take(cnt, f"{cnt} channel names")]
        bad = [c for c in chans if c.lower() not in _CHANNELS]
        if bad or len({c.lower() for c in chans}) != cnt:
            raise ParseError(
                path,
                ln,
                f"expected {cnt} distinct channels among X/Y/Z position/rotation, found {' '.join(chans)!r}",
            )
        j.channels = chans
        self.i += cnt

    def close(self, ln: int) -> None:
        if not self.stack:
            raise ParseError(self.path, ln, "unbalanced '}'")
        j = self.joints[self.stack.pop()]
        if j.offset is None:
            what = f"End Site of {self.joints[j.parent].name!r}" if j.name is None else f"joint {j.name!r}"
            raise ParseError(self.path, ln, f"{what} has no OFFSET")
        self.i += 1


def _motion_header(path: Path, data: bytes, pos: int, line: int) -> tuple[int, float, int, int]:
    """Frames, frame time, byte offset and line of the first data line after MOTION."""
    vals: dict[str, str] = {}
    last = line_of(data, len(data))
    for key, shown in (("frames:", "Frames:"), ("frame time:", "Frame Time:")):
        end = data.find(b"\n", pos)
        end = len(data) if end < 0 else end
        while not data[pos:end].strip() and end < len(data):  # blank lines (peers skip them too)
            pos, line = end + 1, line + 1
            end = data.find(b"\n", pos)
            end = len(data) if end < 0 else end
        text = data[pos:end].strip().decode("latin-1")
        if not text.lower().startswith(key) or len(text) == len(key):
            what = "the file ends" if pos >= len(data) else f"found {text[:40]!r}"
            raise ParseError(path, min(line, last), f"expected '{shown} <value>', {what}")
        vals[key] = text[len(key) :].strip(" \t\r\x0b\x0c")
        pos, line = end + 1, line + 1
    try:
        frames = strict_int(vals["frames:"])
        dt = strict_float(vals["frame time:"])
    except ValueError:
        raise ParseError(path, line - 2, f"expected an integer frame count and a frame time, found {vals}") from None
    if frames < 1:
        raise ParseError(path, line - 2, f"expected Frames >= 1, found {frames}")
    if not 1.0 / MAX_FPS <= dt <= 3600.0:
        raise ParseError(
            path,
            line - 1,
            f"expected a Frame Time between {1.0 / MAX_FPS:g} s ({MAX_FPS:g} Hz) and 3600 s, found {dt:g}",
        )
    return frames, dt, pos, line


def skeleton_span(parents: np.ndarray, offsets: np.ndarray) -> float:
    """The longest path between two joints along the bones, summing bone lengths (``|OFFSET|``
    of every non-root joint): fingertip to toe for a person. It depends on the bone lengths
    only, never on the directions of the OFFSETs (the rest pose an exporter wrote: T-pose,
    A-pose, the clip's first frame), so every clip of one character gives the same value."""
    with np.errstate(over="ignore", invalid="ignore"):
        length = np.linalg.norm(offsets, axis=1)
    down = np.zeros(len(parents))  # longest path from a joint down into its subtree
    best = 0.0
    for j in range(len(parents) - 1, 0, -1):  # children come after their parents
        p = parents[j]
        reach = length[j] + down[j]
        best = max(best, down[p] + reach)  # through p: its longest branch so far and this one
        down[p] = max(down[p], reach)
    return float(best)


def _auto_scale(parents: np.ndarray, offsets: np.ndarray) -> tuple[float, str, float | None]:
    span = skeleton_span(parents, offsets)
    if not 0 < span < np.inf:
        return 1.0, "m", span
    unit = min(BVH_UNITS, key=lambda u: abs(np.log(span * BVH_UNITS[u] / TYPICAL_SPAN_M)))
    return BVH_UNITS[unit], unit, span


def read_bvh(path: str | Path, scale: float | str = "auto", collapse_static_root: bool = True) -> Motion:
    """Read a BVH motion. ``scale``: metres per file unit, a unit of :data:`BVH_UNITS`, or
    ``"auto"`` (guessed from the bone lengths, module doc); ``collapse_static_root`` drops a root joint that never moves when its only
    child carries the translation (Bandai-Namco's ``joint_Root`` above ``Hips``), so that
    ``root_translation`` and ``rotations[:, 0]`` describe the body (module doc for both).

    Positions in metres; metadata ``path``, ``format`` ("bvh"), ``checksum``, ``source_fps``,
    ``source_frames``, ``frame_time``, ``scale``, ``unit``, ``unit_source`` ("guessed from the
    bone lengths" or "given"), ``span`` (:func:`skeleton_span`, file units, when guessed),
    ``subject``, ``collapsed_root``
    (a dropped static root, or None). ParseError names the file, line and what was expected.
    """
    path = Path(path)
    blocks = TextBlocks(
        path, lambda head: text_head(path, head, (b"HIERARCHY",), "'HIERARCHY' at the start of a BVH file")
    )
    joints, frames, dt, table, frame_lines = _read_streaming(path, blocks)

    names = tuple(str(j.name) for j in joints)  # End Sites are named by now
    parents = np.array([j.parent for j in joints])
    offsets = np.array([j.offset for j in joints], dtype=float)
    if scale == "auto":
        scl, unit, span = _auto_scale(parents, offsets)
        unit_source = "guessed from the bone lengths"
    elif isinstance(scale, str) and scale in BVH_UNITS:
        scl, unit, span, unit_source = BVH_UNITS[scale], scale, None, "given"
    else:
        if isinstance(scale, str) or not float(scale) > 0 or not np.isfinite(float(scale)):
            raise DataError(f"scale must be positive, 'auto' or a unit among {sorted(BVH_UNITS)}, got {scale!r}")
        scl, unit, span, unit_source = float(scale), "given", None, "given"
    _check_bounds(path, joints, offsets, table, frame_lines, scl)
    nj = len(joints)
    cols = np.full((nj, 3), -1, dtype=np.int64)
    axis_id = np.zeros((nj, 3), dtype=np.int64)
    pos_cols = np.full((nj, 3), -1, dtype=np.int64)
    c = 0
    for j, jt in enumerate(joints):
        r = 0
        for ch in jt.channels:
            a = "xyz".index(ch[0].lower())
            if ch[1:].lower() == "rotation":
                cols[j, r], axis_id[j, r] = c, a
                r += 1
            else:
                pos_cols[j, a] = c
            c += 1
    root_t = np.empty((frames, 3))
    for a in range(3):
        root_t[:, a] = table[:, pos_cols[0, a]] if pos_cols[0, a] >= 0 else offsets[0, a]
    # joint translations (file units) of non-root joints whose position channels move
    moving: dict[int, np.ndarray] = {}
    for j in range(1, nj):
        if (pos_cols[j] >= 0).any():
            v = np.where(pos_cols[j] >= 0, table[:, np.maximum(pos_cols[j], 0)], offsets[j])
            if np.abs(v - offsets[j]).max() > 1e-4 * max(1.0, float(np.abs(offsets[j]).max())):
                moving[j] = v
    branch = _branch(joints, table)  # the Euler branch of the file's angles, before the table goes
    # the root's rotation alone first (frames x 4): whether it is a static dummy decides which
    # joints are converted, so the rotations are never copied to drop it
    rot0 = _rotations([table], cols[:1], axis_id[:1], 1, shrink=False)
    collapse = bool(
        collapse_static_root
        and 1 in moving
        and (parents == 0).sum() == 1
        and np.ptp(root_t, axis=0).max() <= 1e-9
        and np.abs(rot0[:, 0] - rot0[0, 0]).max() <= 1e-12
    )
    held = [table]
    del table  # the only name left is in `held`: the conversion may shrink it in place
    rot = _rotations(held, cols[1:], axis_id[1:], nj - 1) if collapse else _rotations(held, cols, axis_id, nj)
    names, collapsed, restore = tuple(str(jt.name) for jt in joints), None, None
    chans = [tuple(jt.channels) for jt in joints]
    if collapse:
        # a static dummy root (Bandai-Namco's joint_Root) above the real, translating hips:
        # make the hips the root so that root_translation and rotations[:, 0] carry the motion
        collapsed = names[0]
        r0 = rot0[0, 0].copy()
        # what the writer needs to put it back (a rig that binds by name keeps its root)
        restore = {
            "name": collapsed,
            "offset": offsets[0].tolist(),
            "channels": list(chans[0]),
            "rotation": r0.tolist(),
            "translation": root_t[0].tolist(),
        }
        root_t = root_t[0] + quat.rotate(r0, moving.pop(1))
        rot[:, 0] = quat.mul(r0, rot[:, 0])  # rot holds joints 1.. already
        names, chans = names[1:], chans[1:]
        parents = np.maximum(parents[1:] - 1, -1)
        offsets = offsets[1:]
        moving = {j - 1: v for j, v in moving.items()}
        nj -= 1
    local_t = None
    if moving:
        local_t = np.broadcast_to(offsets * scl, (frames, nj, 3)).copy()
        for j, v in moving.items():
            local_t[:, j] = v * scl
    skeleton = Skeleton(
        names=names,
        parents=parents,
        offsets=offsets * scl,
        canonical=canonical_map(names, "bvh", registered_joint_maps()),
        rotation_orders=tuple("".join(ch[0].lower() for ch in c if ch[1:].lower() == "rotation") for c in chans),
        axes=None,
        channels=tuple(chans),
        name=path.stem,
        meta={"format": "bvh", "scale": scl, "unit": unit, **({"collapsed_root": restore} if restore else {})},
    )
    meta = blocks.metadata("bvh")
    meta.update(branch)
    meta.update(
        subject=path.parent.name,
        source_fps=1.0 / dt,
        source_frames=frames,
        frame_time=dt,
        scale=scl,
        unit=unit,
        unit_source=unit_source,
        span=span,
        collapsed_root=collapsed,
    )
    return Motion(
        skeleton=skeleton,
        root_translation=root_t * scl,
        rotations=rot,
        fps=1.0 / dt,
        name=path.stem,
        metadata=meta,
        local_translations=local_t,
    )


def _branch(joints: list[_Joint], table: np.ndarray) -> dict[str, dict[str, Any]]:
    """``{euler_branch: ...}`` where the file's angles leave the principal Euler branch
    (:mod:`._euler_branch`), else ``{}``."""
    channels: dict[str, np.ndarray] = {}
    triples: dict[str, np.ndarray] = {}
    c = 0
    for jt in joints:
        rot = []
        for ch in jt.channels:
            if ch[1:].lower() == "rotation":
                channels[f"{jt.name}.{ch}"] = table[:, c]
                rot.append(c)
            c += 1
        if len(rot) == 3:
            triples[str(jt.name)] = table[:, rot[1]]
    branch = euler_branch.record(channels, triples)
    return {euler_branch.KEY: branch} if branch["turns"] or branch["flips"] else {}


def _header_ready(head: bytes, after: int) -> bool:
    """Whether ``head`` holds two non-blank lines after byte ``after`` (the MOTION header),
    each ended by LF: :func:`_motion_header` then reads them as it would in the whole file."""
    found, pos = 0, after
    while found < 2:
        end = head.find(b"\n", pos)
        if end < 0:
            return False
        found += bool(head[pos:end].strip())
        pos = end + 1
    return True


def _read_streaming(path: Path, blocks: TextBlocks) -> tuple[list[_Joint], int, float, np.ndarray, np.ndarray]:
    """Joints, frames, frame time, the MOTION table (frames x channels, float64) and the
    line of each frame, the file read in blocks of lines (:class:`._stream.TextBlocks`):
    the blocks up to the MOTION header are kept for the hierarchy, the data lines are parsed
    straight into the table (:func:`._bvh_rows.parse_rows`). The errors are those of
    the whole-file parser, in its order: binary bytes anywhere first, then the hierarchy and
    the header, then the data (a non-number, a line of the wrong count, the frame count)."""
    it = iter(blocks)
    parts: list[bytes] = []
    size = 0
    m = None
    start = None
    last_line = 1
    for block, line in it:
        parts.append(block)
        last_line = line + block.count(b"\n")
        if m is None:
            found = _MOTION_RE.search(block)
            if found is not None:
                m, start = found, size
        size += len(block)
        if m is not None and start is not None and _header_ready(b"".join(parts), start + m.end()):
            break
    head = b"".join(parts)
    del parts
    pending: ParseError | None = None
    joints: list[_Joint] = []
    frames, dt, dpos, dline = 0, 0.0, 0, 0
    try:
        if m is None or start is None:
            raise ParseError(path, last_line, "expected a MOTION section")
        mstart = start + m.start()
        joints = _parse_hierarchy(path, head[:mstart])
        mline = line_of(head, mstart)
        frames, dt, dpos, dline = _motion_header(path, head, start + m.end() + 1, mline + 1)
    except ParseError as exc:  # binary bytes later in the file come first, as in the whole-file check
        pending = exc
    if pending is not None:
        for _ in it:
            pass
        raise pending
    from ._bvh_rows import parse_rows, table_state

    n_ch = sum(len(j.channels) for j in joints)
    stat_size = path.stat().st_size
    rows = min(frames, stat_size // (2 * max(n_ch, 1)) + 1)  # each value takes >= 2 bytes of the file
    table = np.empty((rows, n_ch))
    frame_lines = np.zeros(rows, dtype=np.int64)
    state = table_state()
    parse_rows(head[dpos:], dline, table, frame_lines, state)
    del head
    for block, line in it:
        parse_rows(block, line, table, frame_lines, state)
    _check_motion(path, state, frames, n_ch, dline)
    return joints, frames, dt, table, frame_lines


class BvhFormat(Format):
    """Biovision BVH motions: reader and writer."""

    name: ClassVar[str] = "bvh"
    extensions: ClassVar[tuple[str, ...]] = (".bvh",)
    produces: ClassVar[str] = "motion"

    class Params(BaseParams):
        scale: float | Literal["auto", "m", "cm", "mm", "inch", "asf_cmu"] = Field(
            "auto", description="metres per file unit, a unit name, or 'auto' (guessed from the bone lengths)"
        )

    params: Params

    def read(self, path: str | Path) -> Motion:
        return read_bvh(path, scale=self.params.scale)

    def write(self, obj: Any, path: str | Path) -> None:
        write_bvh(obj, path)
