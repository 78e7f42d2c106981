"""Acclaim ASF/AMC motion files (CMU and HDM05 dialects).

AMC files hold one block per frame: a frame-number line, then one line per bone with the
bone's ``dof`` values (root: the channels of the ASF ``:root order``). Line endings may
be CRLF, LF or both in one file (HDM05 frame-number lines end in LF, the others CRLF).
AMC carries no frame rate: CMU and HDM05 are captured at 120 Hz, the default ``fps``.

The mapping from ASF bones to joints and rotations is documented in
:mod:`mocapflow.plugins.formats._asf`. Parsing is vectorised: the bytes are tokenized
once (:mod:`._text_kernels`) and the regular frame layout is validated with numpy; only a file
that does not follow the layout of its first frame takes a slower token-by-token path,
which either reads it (bones in another order per frame) or reports the first bad line.

Checked against the cgspeed BVH conversion of CMU 01_01 (``tests/plugins/formats/test_formats_bvh.py``):
root, legs and trunk agree to < 1e-5 m; joints above the chest differ by the constant
0.117 m thorax length that the cgspeed skeleton drops, and agree to < 1e-5 m relative to
the neck (fingers: 0.097 m, the dropped wrist bone). The plain per-frame matrix FK of
``benchmarks/ingest.py`` agrees to 1e-15 m.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from pydantic import Field

from mocapflow.framework.components import Format
from mocapflow.framework.components import Params as BaseParams
from mocapflow.framework.errors import DataError, ParseError
from mocapflow.framework.motion import Motion
from mocapflow.framework.skeleton import Skeleton

from . import _euler_branch as euler_branch
from ._amc_write import NotAnAsfSkeleton, write_amc
from ._asf import read_asf as _read_asf_uncached
from ._asf import write_asf
from ._asf_convert import asf_motion
from ._common import MAX_DEGREES, MAX_METRES, check_text, file_metadata, read_bytes, text_body, text_head

__all__ = ["AmcFormat", "NotAnAsfSkeleton", "read_amc", "read_asf", "write_amc", "write_asf", "find_asf"]

#: Default frame rate of AMC files (CMU and HDM05 capture at 120 Hz).
AMC_DEFAULT_FPS = 120.0

_ASF_CACHE: dict[tuple[str, int, int], Skeleton] = {}


def read_asf(path: str | Path) -> Skeleton:
    """Read an ASF skeleton (see :func:`._asf.read_asf`); cached by path, size and mtime."""
    p = Path(path)
    try:
        st = p.stat()
        key = (str(p.resolve()), st.st_mtime_ns, st.st_size)
    except OSError:
        return _read_asf_uncached(p)  # raises the ParseError
    sk = _ASF_CACHE.get(key)
    if sk is None:
        sk = _read_asf_uncached(p)
        if len(_ASF_CACHE) > 256:
            _ASF_CACHE.clear()
        _ASF_CACHE[key] = sk
    return sk


def find_asf(amc_path: str | Path) -> Path:
    """The ASF of an AMC file: the only ``.asf`` in its folder, else the one whose stem is
    the longest prefix of the AMC's stem (``01.asf`` for ``01_01.amc``)."""
    p = Path(amc_path)
    cands = sorted(q for q in p.parent.glob("*") if q.suffix.lower() == ".asf" and q.is_file())
    if len(cands) == 1:
        return cands[0]
    stem = p.stem.lower()
    best = [q for q in cands if stem.startswith(q.stem.lower())]
    if best:
        return max(best, key=lambda q: len(q.stem))
    where = f"{len(cands)} .asf files, none a prefix of {p.stem!r}" if cands else "no .asf file"
    raise ParseError(p, None, f"cannot find the ASF skeleton: its folder has {where}; pass skeleton=")


def _subject(path: Path) -> str:
    m = re.match(r"HDM_([A-Za-z]+)_", path.stem)
    if m:
        return m.group(1)
    return path.parent.name or path.stem.split("_")[0]


def _header(path: Path, data: bytes) -> tuple[int, int, str | None, bool]:
    """Byte offset and line number of the first frame line, the angle unit if given and
    whether the header says ``:FULLY-SPECIFIED``."""
    pos = 0
    ln = 1
    unit = None
    full = False
    n = len(data)
    while pos < n:
        end = data.find(b"\n", pos)
        end = n if end < 0 else end
        text = data[pos:end].strip()
        if text[:1].isdigit():
            if not text.isdigit() or len(text) > 9:
                raise ParseError(
                    path,
                    ln,
                    f"expected a frame number (digits only, below 10^9) alone on its line, "
                    f"found {text[:40].decode('latin-1')!r}",
                )
            return pos, ln, unit, full
        if text and text[:1] not in (b"#", b":"):
            raise ParseError(
                path, ln, f"expected a header line or frame number 1, found {text[:40].decode('latin-1')!r}"
            )
        up = text.upper()
        if up == b":DEGREES":
            unit = "deg"
        elif up == b":RADIANS":
            unit = "rad"
        elif up == b":FULLY-SPECIFIED":
            full = True
        pos = end + 1
        ln += 1
    raise ParseError(path, ln - 1, "expected frame blocks after the header, found none")


def _layout(
    path: Path, data: bytes, tok: tuple[Any, ...], skeleton: Skeleton
) -> tuple[list[tuple[str, int, int]], int]:
    """Bone names and value columns of the first frame (the layout every frame should follow).

    Returns ``[(name, first value column, count)]`` and the table width (frame number
    and, per bone, its name and values). Only names are checked here (defined, once);
    value counts and line structure are checked by :func:`_fast_values` or, when that
    fails, :func:`_slow_values`, completeness by :func:`_check_complete`.
    """
    starts, lens, lines, _h, values, isnum = tok[:6]
    n = len(starts)
    chan_of = {name: len(skeleton.channels[j]) for j, name in enumerate(skeleton.names) if skeleton.channels[j]}
    bones: list[tuple[str, int, int]] = []  # name, first value column, count
    seen: set[str] = set()
    i = 1
    while i < n and not isnum[i]:
        name = data[starts[i] : starts[i] + lens[i]].decode("latin-1")
        if name not in chan_of:
            raise ParseError(
                path, int(lines[i]), f"bone {name!r} is not defined (with dofs) in the ASF skeleton {skeleton.name!r}"
            )
        if name in seen:
            raise ParseError(path, int(lines[i]), f"frame 1: bone {name!r} appears twice")
        seen.add(name)
        bones.append((name, i + 1, chan_of[name]))
        i += 1 + chan_of[name]
    if not bones:
        raise ParseError(
            path, int(lines[min(i, n) - 1]) if n else 1, "frame 1: expected bone lines after the frame number"
        )
    return bones, i


def _check_complete(path: Path, skeleton: Skeleton, bones: list[tuple[str, int, int]], line: int) -> None:
    """A ``:FULLY-SPECIFIED`` file lists every bone that has dofs in every frame."""
    have = {b for b, _, _ in bones}
    missing = [n for j, n in enumerate(skeleton.names) if skeleton.channels[j] and n not in have]
    if missing:
        raise ParseError(
            path,
            line,
            f"frame 1 is incomplete (the file is :FULLY-SPECIFIED): expected bones "
            f"{', '.join(missing[:5])}" + ("..." if len(missing) > 5 else ""),
        )


def _fast_values(
    data: bytes, tok: tuple[Any, ...], bones: list[tuple[str, int, int]], width: int
) -> tuple[np.ndarray, np.ndarray, int] | None:
    """``(table (T, width), token lines (T, width), T)`` if every frame follows the first
    frame's layout exactly (names, numbers, one line per bone and per frame number,
    consecutive frame numbers), else None."""
    from ._text_kernels import fnv1a

    starts, _l, lines, hashes, values, isnum = tok[:6]
    n = len(starts)
    if n == 0 or n % width:
        return None
    t = n // width
    num = isnum.reshape(t, width)
    vals = values.reshape(t, width)
    name_cols = np.array([c - 1 for _, c, _ in bones], dtype=np.int64)
    value_mask = np.ones(width, bool)
    value_mask[name_cols] = False
    if not num[:, value_mask].all():
        return None
    expected = np.array([fnv1a(b.encode("latin-1")) for b, _, _ in bones], dtype=np.uint64)
    if not (hashes.reshape(t, width)[:, name_cols] == expected).all():
        return None
    if not np.array_equal(vals[:, 0], vals[0, 0] + np.arange(t)):
        return None
    # a new line starts exactly at each frame number and bone name, nowhere else
    new_line = np.zeros(width, bool)
    new_line[0] = True
    new_line[name_cols] = True
    if not np.array_equal(np.diff(lines) > 0, np.tile(new_line, t)[1:]):
        return None
    return vals, lines.reshape(t, width), t


def _slow_values(
    path: Path, data: bytes, tok: tuple[Any, ...], bones: list[tuple[str, int, int]]
) -> tuple[np.ndarray, np.ndarray, int]:
    """Token-by-token reading with exact error lines; accepts any bone order per frame.

    Returns ``(table (T, width), token lines (T, width), T)`` in the first frame's layout.
    """
    starts, lens, lines, _h, values, isnum = tok[:6]
    n = len(starts)
    count = {b: k for b, _, k in bones}
    order = [b for b, _, _ in bones]

    def text(i: int) -> str:
        return data[starts[i] : starts[i] + lens[i]].decode("latin-1")

    out: dict[str, list[np.ndarray]] = {b: [] for b in order}
    out_lines: dict[str, list[int]] = {b: [] for b in order}
    frame_lines: list[int] = []
    i = 0
    frame = None
    while i < n:
        ln = int(lines[i])
        v = values[i]
        expect = "an integer frame number" if frame is None else f"frame number {frame + 1}"
        if not isnum[i] or v != int(v) or (frame is not None and v != frame + 1):
            raise ParseError(path, ln, f"expected {expect}, found {text(i)!r}")
        if i + 1 < n and lines[i + 1] == ln:
            raise ParseError(
                path, ln, f"expected frame number {int(v)} alone on its line, found {text(i + 1)!r} after it"
            )
        frame = int(v)
        frame_lines.append(ln)
        i += 1
        seen: set[str] = set()
        while i < n and not isnum[i]:
            name, ln = text(i), int(lines[i])
            if name not in count:
                raise ParseError(
                    path, ln, f"frame {frame}: bone {name!r} is not in the first frame or has no dofs in the ASF"
                )
            if name in seen:
                raise ParseError(path, ln, f"frame {frame}: bone {name!r} appears twice")
            if i > 0 and lines[i - 1] == ln:
                raise ParseError(path, ln, f"frame {frame}: expected bone {name!r} at the start of a line")
            seen.add(name)
            k = count[name]
            j = i + 1
            while j < n and j - i - 1 < k + 1 and lines[j] == ln:
                j += 1
            got = j - i - 1
            if got != k:
                raise ParseError(path, ln, f"frame {frame}: expected {k} values for bone {name!r}, found {got}")
            for m in range(i + 1, j):
                if not isnum[m]:
                    raise ParseError(
                        path, ln, f"frame {frame}: expected a finite number for bone {name!r}, found {text(m)!r}"
                    )
            out[name].append(values[i + 1 : j])
            out_lines[name].append(ln)
            i = j
        if len(seen) != len(order):
            missing = [b for b in order if b not in seen]
            last = int(lines[i - 1])
            what = "file ends" if i >= n else f"frame {frame + 1} starts"
            raise ParseError(
                path,
                last,
                f"frame {frame} is incomplete ({what}): expected bones {', '.join(missing[:5])}"
                + ("..." if len(missing) > 5 else ""),
            )
    t = len(frame_lines)
    width = 1 + sum(1 + k for k in count.values())
    table = np.zeros((t, width))
    line_table = np.zeros((t, width), dtype=np.int64)
    line_table[:, 0] = frame_lines
    for b, c, k in bones:
        table[:, c : c + k] = np.array(out[b]).reshape(t, k)
        line_table[:, c - 1 : c + k] = np.array(out_lines[b])[:, None]
    return table, line_table, t


def _check_bounds(
    path: Path,
    skeleton: Skeleton,
    table: np.ndarray,
    line_table: np.ndarray,
    bones: list[tuple[str, int, int]],
    degrees: bool,
    scale: float,
) -> None:
    """Angles within MAX_DEGREES, root translations within MAX_METRES (``_common``)."""
    limit = np.full(table.shape[1], np.inf)
    kind = [""] * table.shape[1]
    index = {n: j for j, n in enumerate(skeleton.names)}
    for name, c0, _k in bones:
        for c, ch in enumerate(skeleton.channels[index[name]], start=c0):
            if ch[0] == "T":
                limit[c], kind[c] = MAX_METRES / scale, f"a root translation within {MAX_METRES:g} m"
            else:
                limit[c] = MAX_DEGREES if degrees else np.deg2rad(MAX_DEGREES)
                kind[c] = f"an angle within {limit[c]:g} {'degrees' if degrees else 'radians'}"
    over = np.abs(table) > limit
    if over.any():
        f, c = np.argwhere(over)[0]
        raise ParseError(
            path,
            int(line_table[f, c]),
            f"frame {table[f, 0]:.0f}: expected {kind[c]}, found {table[f, c]:g} (bone {_bone_of_col(bones, c)!r})",
        )


def _bone_of_col(bones: list[tuple[str, int, int]], c: int) -> str:
    return next(b for b, c0, k in bones if c0 <= c < c0 + k)


def read_amc(
    path: str | Path,
    skeleton: Skeleton | str | Path | None = None,
    fps: float = AMC_DEFAULT_FPS,
) -> Motion:
    """Read an AMC motion with ``skeleton`` (from :func:`read_asf`, its ASF path, or ``None``:
    :func:`find_asf`) at ``fps`` (AMC files carry none; CMU and HDM05 are 120 Hz).

    Returns ``rotations (T, J, 4)``, ``root_translation (T, 3)`` in metres; metadata ``path``,
    ``format`` ("amc"), ``subject``, ``checksum`` (sha1 of the bytes), ``source_fps``,
    ``source_frames``, ``skeleton_path``. ParseError names the file, the 1-based line and
    what was expected.
    """
    path = Path(path)
    data = read_bytes(path, lambda head: text_head(path, head, (), "AMC motion"))
    from ._text_kernels import tokenize  # after the header check: a foreign file costs no kernel load

    skel_path = None
    if skeleton is None:
        skeleton = skel_path = find_asf(path)
    if isinstance(skeleton, Skeleton):
        skel = skeleton
    else:
        skel_path = Path(skeleton)
        skel = read_asf(skel_path)
    if not skel.channels or skel.axes is None:
        raise DataError(f"skeleton {skel.name!r} has no ASF channels/axes; read it with read_asf")
    body = text_body(data)
    check_text(path, body)
    start, first_line, unit, full = _header(path, body)
    degrees = (unit or skel.meta.get("units", {}).get("angle", "deg")) == "deg"
    buf = np.frombuffer(body, dtype=np.uint8)
    tok = tokenize(buf, start, first_line)
    if tok[6] >= 0:  # check_text already rejects these; never read a cut-off token stream
        raise ParseError(path, int(tok[7]), "expected text, found a binary control byte")
    bones, width = _layout(path, body, tok, skel)
    fast = _fast_values(body, tok, bones, width)
    table, line_table, t = fast if fast is not None else _slow_values(path, body, tok, bones)
    if full:
        _check_complete(path, skel, bones, int(line_table[0, -1]))
    scale = float(skel.meta.get("length_scale", 0.0254 / 0.45))
    _check_bounds(path, skel, table, line_table, bones, degrees, scale)
    root_t, rot = _to_motion_arrays(skel, table, bones, degrees)
    meta = file_metadata(path, data, "amc")
    meta.update(
        subject=_subject(path),
        source_fps=float(fps),
        source_frames=int(t),
        skeleton_path=str(skel_path) if skel_path else skel.meta.get("path", ""),
        angle_unit="deg" if degrees else "rad",
    )
    branch = _branch(skel, table, bones, degrees)
    if branch["turns"] or branch["flips"]:
        meta[euler_branch.KEY] = branch
    return Motion(skeleton=skel, root_translation=root_t, rotations=rot, fps=fps, name=path.stem, metadata=meta)


def _branch(skeleton: Skeleton, table: np.ndarray, bones: list[tuple[str, int, int]], degrees: bool) -> dict[str, Any]:
    """Where the file's angles leave the principal Euler branch (:mod:`._euler_branch`)."""
    index = {n: j for j, n in enumerate(skeleton.names)}
    channels, triples = {}, {}
    for name, c0, _k in bones:
        rot = [(c, ch) for c, ch in enumerate(skeleton.channels[index[name]], start=c0) if ch[0] in "Rr"]
        for c, ch in rot:
            channels[f"{name}.{ch.lower()}"] = table[:, c]
        if len(rot) == 3:
            triples[name] = table[:, rot[1][0]]
    return euler_branch.record(channels, triples, degrees)


def _to_motion_arrays(
    skeleton: Skeleton, table: np.ndarray, bones: list[tuple[str, int, int]], degrees: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Root translation (T, 3) metres and local rotations (T, J, 4) from the frame table.

    ``bones`` lists (name, first column, count) of the table's bone values. Rotations
    are ``C M C^-1`` with ``M`` the dof rotations about fixed axes in listed order
    (:func:`._kernels.euler_table_to_quat`).
    """
    from ._kernels import euler_table_to_quat, readonly

    scale = float(skeleton.meta.get("length_scale", 0.0254 / 0.45))
    n_j = skeleton.n_joints
    cols = np.full((n_j, 3), -1, dtype=np.int64)
    axis_id = np.zeros((n_j, 3), dtype=np.int64)
    root_t = np.zeros((len(table), 3))
    index = {n: j for j, n in enumerate(skeleton.names)}
    for name, c0, _k in bones:
        j = index[name]
        n_rot = 0
        for c, ch in enumerate(skeleton.channels[j], start=c0):
            if ch[0] == "T":  # root translation channel
                root_t[:, "XYZ".index(ch[1])] = table[:, c] * scale
            else:
                cols[j, n_rot] = c
                axis_id[j, n_rot] = "xyz".index(ch[1].lower())
                n_rot += 1
    rot = euler_table_to_quat(
        np.ascontiguousarray(table),
        cols,
        axis_id,
        readonly(np.ascontiguousarray(skeleton.axes)),
        np.pi / 180.0 if degrees else 1.0,
        True,
    )
    return root_t, rot


class AsfFormat(Format):
    """Acclaim ASF skeletons on their own (a performer's bones: what other plugins, such as
    reconstruction, take as an output skeleton). Reader only; returns a Skeleton."""

    name: ClassVar[str] = "asf"
    extensions: ClassVar[tuple[str, ...]] = (".asf",)
    produces: ClassVar[str] = "skeleton"

    def read(self, path: str | Path) -> Any:
        return read_asf(path)


class AmcFormat(Format):
    """Acclaim AMC motions (with the ASF skeleton beside them): reader and writer."""

    name: ClassVar[str] = "amc"
    extensions: ClassVar[tuple[str, ...]] = (".amc",)
    produces: ClassVar[str] = "motion"

    class Params(BaseParams):
        fps: float = Field(
            AMC_DEFAULT_FPS, gt=0, description="frame rate of the AMC files (they carry none; CMU/HDM05: 120)"
        )
        asf: str | None = Field(None, description="ASF skeleton path; default: the .asf beside each AMC file")

    params: Params

    def read(self, path: str | Path) -> Motion:
        return read_amc(path, skeleton=self.params.asf, fps=self.params.fps)

    def write(self, obj: Any, path: str | Path) -> None:
        """AMC with its ASF beside it (same stem), so that it reads back; a motion from
        another format gets an ASF made from its skeleton (:mod:`._asf_convert`)."""
        obj = asf_motion(obj)  # before any file is created: a refusal leaves nothing behind
        write_amc(obj, path)
        write_asf(obj.skeleton, Path(path).with_suffix(".asf"))

    def write_atomic(self, obj: Any, path: str | Path) -> None:
        """The ASF beside ``path`` and then the AMC, each through a temporary file renamed
        into place (the ASF is named after ``path``, not after the temporary AMC)."""
        from mocapflow.framework.workspace import atomic_path

        obj = asf_motion(obj)
        with atomic_path(Path(path).with_suffix(".asf")) as tmp:
            write_asf(obj.skeleton, tmp)
        with atomic_path(path) as tmp:
            write_amc(obj, tmp)
