"""Slow, obviously correct reference readers of AMC, BVH and TRC files: the oracle of the
parser fuzzer (``benchmarks/fuzz_parsers.py``, ``tests/plugins/formats/test_fuzz_parsers.py``).

They share no parsing code with ``plugins/formats``: each splits the file into lines
(LF, CRLF or a lone CR) and words (``bytes.split``), reads numbers with ``float`` after a
regular expression says they are plain decimals, and restates the rules the readers
document, one line at a time, in the most direct way. A reader returns plain arrays of
what the file says, or raises :class:`Reject` with the line of the first problem.

Rules restated here (they are the format contracts of ``plugins/formats``):

* a UTF-8 BOM at the start is ignored; bytes 0x00-0x08, 0x0e-0x1f and 0x7f are binary
  garbage; ASCII space, tab, CR, VT and FF separate words;
* a number is ``[+-]digits[.digits][e[+-]digits]`` (or ``.digits``) and finite; ``nan``,
  ``inf`` and overflowing numbers are not numbers;
* positions beyond 10 km, angles beyond 10^6 degrees and frame rates above 100 kHz are
  rejected (``plugins/formats/_common.py``, "Value policy").
"""

from __future__ import annotations

import math
import re

import numpy as np

from mocapflow.framework import quaternions as quat

MAX_METRES = 1.0e4
MAX_DEGREES = 1.0e6
MAX_FPS = 1.0e5
_NUMBER = re.compile(rb"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_BINARY = re.compile(rb"[\x00-\x08\x0e-\x1f\x7f]")
_EOL = re.compile(rb"\r\n|\r|\n")


class Reject(Exception):
    """The reference reader refuses the file at ``line`` (1-based) because of ``message``."""

    def __init__(self, line: int, message: str) -> None:
        super().__init__(f"line {line}: {message}")
        self.line, self.message = line, message


def number(word: bytes) -> float | None:
    """The value of a plain finite decimal number, None for any other word."""
    if not _NUMBER.fullmatch(word):
        return None
    v = float(word)
    return v if math.isfinite(v) else None


def numbers(words: list[bytes]) -> list[float] | None:
    """The values of words that are all plain finite numbers, else None."""
    if not all(map(_NUMBER.fullmatch, words)):
        return None
    vals = list(map(float, words))
    return vals if all(map(math.isfinite, vals)) else None


def text_lines(data: bytes) -> list[bytes]:
    """The file's lines without line ends, after the BOM and binary checks."""
    if not data.strip():
        raise Reject(1, "empty file")
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    m = _BINARY.search(data)
    if m:
        raise Reject(len(_EOL.findall(data[: m.start()])) + 1, "binary byte")
    return _EOL.split(data)


# --- AMC -------------------------------------------------------------------------------


def read_amc(data: bytes, skeleton) -> dict:
    """What an AMC file says, for the ASF ``skeleton`` (a Skeleton from ``read_asf``).

    Returns ``{"frames": T, "degrees": bool, "values": {bone: ndarray (T, k)}}``; the
    values of each bone in the ASF's dof order, file units.
    """
    lines = text_lines(data)
    dofs = {n: len(ch) for n, ch in zip(skeleton.names, skeleton.channels, strict=True) if ch}
    unit, full, i = _amc_header(lines)
    if i == len(lines):
        raise Reject(i, "no frames")
    first = lines[i].strip()
    if not (first.isdigit() and len(first) <= 9):
        raise Reject(i + 1, "expected a frame number of at most 9 digits")
    degrees = (unit or skeleton.meta.get("units", {}).get("angle", "deg")) == "deg"
    frames: list[dict[str, list[float]]] = []
    frame_numbers: list[float] = []
    for ln in range(i, len(lines)):
        words = lines[ln].split()
        if not words:
            continue
        v = number(words[0])
        if v is not None:  # a frame-number line
            if len(words) != 1 or v != int(v) or (frame_numbers and v != frame_numbers[-1] + 1):
                raise Reject(ln + 1, "expected the next frame number alone on its line")
            if frames:
                _close_frame(frames, ln)
            frame_numbers.append(v)
            frames.append({})
            continue
        name = words[0].decode("latin-1")
        allowed = dofs if len(frames) == 1 else frames[0]
        if name not in allowed or name in frames[-1]:
            raise Reject(ln + 1, f"bone {name!r} not expected here")
        vals = numbers(words[1:])
        if vals is None or len(vals) != dofs[name]:
            raise Reject(ln + 1, f"expected {dofs[name]} numbers for {name!r}")
        frames[-1][name] = vals
    _close_frame(frames, len(lines))
    if full and set(frames[0]) != set(dofs):
        raise Reject(i + 1, "fully specified file lacks bones")
    values = {b: np.array([f[b] for f in frames]) for b in frames[0]}
    index = {n: j for j, n in enumerate(skeleton.names)}
    scale = skeleton.meta["length_scale"]
    for b, v in values.items():
        for c, ch in enumerate(skeleton.channels[index[b]]):
            limit = MAX_METRES / scale if ch[0] == "T" else (MAX_DEGREES if degrees else math.radians(MAX_DEGREES))
            if np.abs(v[:, c]).max() > limit:
                raise Reject(i + 1, f"{b} {ch} out of bounds")
    return {"frames": len(frames), "degrees": degrees, "values": values}


def _amc_header(lines: list[bytes]) -> tuple[str | None, bool, int]:
    """The angle unit, :FULLY-SPECIFIED, and the index of the first frame line."""
    unit, full, i = None, False, 0
    while i < len(lines) and not lines[i].strip()[:1].isdigit():
        t = lines[i].strip()
        if t and t[:1] not in (b"#", b":"):
            raise Reject(i + 1, "expected a header line")
        unit = {b":DEGREES": "deg", b":RADIANS": "rad"}.get(t.upper(), unit)
        full = full or t.upper() == b":FULLY-SPECIFIED"
        i += 1
    return unit, full, i


def _close_frame(frames: list[dict], ln: int) -> None:
    if not frames[-1] or (len(frames) > 1 and set(frames[-1]) != set(frames[0])):
        raise Reject(ln, "incomplete frame")


def amc_arrays(content: dict, skeleton) -> tuple[np.ndarray, np.ndarray]:
    """Root translation (T, 3) metres and rotations (T, J, 4) of :func:`read_amc`'s
    content: ``C M C^-1`` with ``M`` the dof rotations about fixed axes, in listed order."""
    t, nj = content["frames"], skeleton.n_joints
    scale = skeleton.meta["length_scale"]
    unit = math.pi / 180 if content["degrees"] else 1.0
    root = np.zeros((t, 3))
    angles = np.zeros((t, nj, 3))  # k-th rotation dof of each joint (0 where it has fewer)
    axes = np.zeros((nj, 3, 3))
    axes[:, :, 0] = 1.0
    for j, (name, chans) in enumerate(zip(skeleton.names, skeleton.channels, strict=True)):
        vals = content["values"].get(name)
        k = 0
        for c, ch in enumerate(chans if vals is not None else ()):
            if ch[0] == "T":
                root[:, "XYZ".index(ch[1])] = vals[:, c] * scale
            else:
                angles[:, j, k] = vals[:, c] * unit
                axes[j, k] = np.eye(3)["xyz".index(ch[1].lower())]
                k += 1
    m = quat.identity((t, nj))
    for k in range(3):  # fixed axes: each later rotation applies on the left
        m = quat.mul(quat.from_axis_angle(axes[:, k], angles[:, :, k]), m)
    c = skeleton.axes
    return root, quat.mul(quat.mul(c, m), quat.conjugate(c))


# --- BVH ---------------------------------------------------------------------------------

_CHANNELS = {b"xposition", b"yposition", b"zposition", b"xrotation", b"yrotation", b"zrotation"}


def _name_end_sites(joints: list[dict]) -> None:
    """Refuse duplicate joint names; name each End Site ``<parent>_end``, ``_end2``..."""
    used = {j["name"] for j in joints if j["name"] is not None}
    if len(used) != sum(j["name"] is not None for j in joints):
        raise Reject(1, "duplicate joint names")
    for j in joints:
        if j["name"] is None:
            base, k = joints[j["parent"]]["name"] + "_end", 2
            name = base
            while name in used:
                name, k = f"{base}{k}", k + 1
            j["name"] = name
            used.add(name)


def read_bvh(data: bytes, scale: float = 1.0) -> dict:
    """What a BVH file says: ``names, parents, offsets (J, 3), channels, table (T, C),
    frame_time``; ``scale`` (metres per file unit) only sets the bounds."""
    lines = text_lines(data)
    try:
        m = next(k for k, ln in enumerate(lines) if ln.strip(b" \t") == b"MOTION")
    except StopIteration:
        raise Reject(len(lines), "no MOTION line") from None
    words = [(w, k + 1) for k in range(m) for w in lines[k].split()]
    words.append((b"", m + 1))  # end marker
    if _kw(words[0][0]) != b"HIERARCHY" or _kw(words[1][0]) != b"ROOT":
        raise Reject(words[0][1], "expected HIERARCHY ROOT")
    joints: list[dict] = []
    pos = _bvh_joint(words, 2, -1, False, joints)
    if words[pos][0] != b"":
        raise Reject(words[pos][1], "words after the root joint")
    _name_end_sites(joints)
    # the Frames: and Frame Time: lines, blank lines before them skipped
    head_at = [k for k in range(m + 1, len(lines)) if lines[k].strip()][:2]
    head = [lines[k].strip() for k in head_at] + [b"", b""]
    if not head[0].lower().startswith(b"frames:") or not head[1].lower().startswith(b"frame time:"):
        raise Reject(m + 2, "expected Frames: and Frame Time:")
    frames, dt_word = head[0][7:].strip(), head[1][11:].strip()
    dt = number(dt_word)
    if not frames.isdigit() or int(frames) < 1 or dt is None or not 1 / MAX_FPS <= dt <= 3600:
        raise Reject(m + 2, "bad Frames or Frame Time")
    n_ch = sum(len(j["channels"]) for j in joints)
    rows = []
    for k in range(head_at[1] + 1, len(lines)):
        ws = lines[k].split()
        if not ws:
            continue
        vals = numbers(ws)
        if vals is None or len(vals) != n_ch:
            raise Reject(k + 1, f"expected {n_ch} numbers")
        rows.append(vals)
    if len(rows) != int(frames):
        raise Reject(len(lines), "frame count differs from Frames:")
    table = np.array(rows, dtype=float).reshape(len(rows), n_ch)
    offsets = np.array([j["offset"] for j in joints], dtype=float)
    if np.abs(offsets).max() * scale > MAX_METRES:
        raise Reject(1, "OFFSET out of bounds")
    kinds = [c.lower().endswith(b"rotation") for j in joints for c in j["channels"]]
    for c, rotation in enumerate(kinds):
        if np.abs(table[:, c]).max() > (MAX_DEGREES if rotation else MAX_METRES / scale):
            raise Reject(m + 4, "channel out of bounds")
    return {
        "names": [j["name"] for j in joints],
        "parents": [j["parent"] for j in joints],
        "offsets": offsets,
        "channels": [tuple(c.decode("latin-1") for c in j["channels"]) for j in joints],
        "table": table,
        "frame_time": dt,
    }


def _kw(word: bytes) -> bytes:
    """A BVH keyword in one case or capitalised (``CHANNELS``, ``channels``, ``Channels``);
    anything else (``CHANnELS``) is no keyword."""
    return word.upper() if word in (word.upper(), word.lower(), word.capitalize()) else b""


def _bvh_joint(words: list[tuple[bytes, int]], pos: int, parent: int, end_site: bool, joints: list[dict]) -> int:
    """Read one joint from ``words[pos]`` (its name, or nothing for an End Site) to its
    closing brace; returns the position after it."""
    name = None
    if not end_site:
        name, pos = words[pos][0].decode("latin-1"), pos + 1
        if words[pos - 1][0] == b"":
            raise Reject(words[pos - 1][1], "file ends")
    me = len(joints)
    joint = {"name": name, "parent": parent, "offset": None, "channels": ()}
    joints.append(joint)
    if words[pos][0] != b"{":
        raise Reject(words[pos][1], "expected {")
    pos += 1
    seen_channels = False
    while True:
        w, ln = words[pos]
        key = _kw(w)
        if w == b"}":
            if joint["offset"] is None:
                raise Reject(ln, "joint without OFFSET")
            return pos + 1
        if key == b"OFFSET" and joint["offset"] is None:
            vals = [number(x) for x, _ in words[pos + 1 : pos + 4]]
            if len(vals) != 3 or any(v is None for v in vals):
                raise Reject(ln, "expected 3 OFFSET numbers")
            joint["offset"] = vals
            pos += 4
        elif key == b"CHANNELS" and not end_site and not seen_channels:
            seen_channels = True
            cnt = words[pos + 1][0]
            if not cnt.isdigit() or int(cnt) > 6:
                raise Reject(ln, "expected a channel count of at most 6")
            chans = [x for x, _ in words[pos + 2 : pos + 2 + int(cnt)]]
            if (
                len(chans) != int(cnt)
                or any(c.lower() not in _CHANNELS for c in chans)
                or len({c.lower() for c in chans}) != len(chans)
            ):
                raise Reject(ln, "bad channels")
            joint["channels"] = tuple(chans)
            pos += 2 + int(cnt)
        elif key == b"JOINT" and not end_site:
            pos = _bvh_joint(words, pos + 1, me, False, joints)
        elif key == b"END" and _kw(words[pos + 1][0]) == b"SITE" and not end_site:
            pos = _bvh_joint(words, pos + 2, me, True, joints)
        else:
            raise Reject(ln, f"unexpected {w!r}")


def bvh_arrays(content: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Root translation (T, 3), rotations (T, J, 4) and moving joint translations
    (T, J, 3) or None, all in file units, of :func:`read_bvh`'s content: rotations
    intrinsic in listed order (``R = R1 R2 R3``); a non-root joint's position channels
    count when they move more than 1e-4 (relative) away from its OFFSET."""
    table, offsets = content["table"], content["offsets"]
    t, nj = table.shape[0], len(offsets)
    angles = np.zeros((t, nj, 3))
    axes = np.zeros((nj, 3, 3))
    axes[:, :, 0] = 1.0
    trans = np.broadcast_to(offsets, (t, nj, 3)).copy()
    c = 0
    for j, chans in enumerate(content["channels"]):
        k = 0
        for ch in chans:
            axis = "xyz".index(ch[0].lower())
            if ch[1:].lower() == "rotation":
                angles[:, j, k] = np.radians(table[:, c])
                axes[j, k] = np.eye(3)[axis]
                k += 1
            else:
                trans[:, j, axis] = table[:, c]
            c += 1
    rot = quat.identity((t, nj))
    for k in range(3):  # intrinsic: each later rotation applies on the right
        rot = quat.mul(rot, quat.from_axis_angle(axes[:, k], angles[:, :, k]))
    moving = [
        j for j in range(1, nj) if np.abs(trans[:, j] - offsets[j]).max() > 1e-4 * max(1.0, np.abs(offsets[j]).max())
    ]
    local = None
    if moving:
        local = np.broadcast_to(offsets, (t, nj, 3)).copy()
        local[:, moving] = trans[:, moving]
    return trans[:, 0], rot, local


# --- TRC ---------------------------------------------------------------------------------

TRC_UNITS = {"mm": 0.001, "cm": 0.01, "m": 1.0, "in": 0.0254, "inch": 0.0254, "dm": 0.1}
_SPACE = b" \t\r\x0b\x0c"


def _header_words(line: bytes) -> list[bytes]:
    return [w for w in re.split(rb"[ \t]+", line.strip(_SPACE)) if w]


def _trc_fields(line: bytes, words: list[bytes], width: int, k: int, last: bool) -> list[float]:
    """A data row with gaps: empty or NaN fields (tab separated) read as NaN; a short row
    other than the last one padded with gaps, a long one cut to ``width`` fields."""
    fields = line.split(b"\t") if b"\t" in line else words
    if len(fields) < width:
        if last or len(fields) < 2:
            raise Reject(k + 1, f"expected {width} fields")
        fields = fields + [b""] * (width - len(fields))
    vals = []
    for f in fields[:width]:
        f = f.strip()
        if not f or f.lstrip(b"+-").lower() == b"nan":
            vals.append(math.nan)
        elif number(f) is None:
            raise Reject(k + 1, f"bad field {f!r}")
        else:
            vals.append(number(f))
    return vals


def read_trc(data: bytes) -> dict:
    """What a TRC file says: ``labels, rate, first_frame, positions (T, M, 3)`` metres,
    NaN for a marker with any empty or NaN coordinate."""
    lines = text_lines(data.replace(b"\r\r\n", b"\r\n"))
    head = (lines + [b""] * 5)[:5]
    if not head[0].startswith(b"PathFileType"):
        raise Reject(1, "expected PathFileType")
    if b"," in head[1] and b"\t" not in head[1]:  # comma-separated
        lines = [ln.replace(b",", b"\t") for ln in lines]
        head = (lines + [b""] * 5)[:5]
    keys, vals = _header_words(head[1]), _header_words(head[2])
    if len(keys) != len(vals):
        keys = [k.strip(_SPACE) for k in head[1].split(b"\t")]
        vals = [v.strip(_SPACE) for v in head[2].split(b"\t")]
    info = {k: v for k, v in zip(keys, vals, strict=False) if k}
    nf, nm = info.get(b"NumFrames", b""), info.get(b"NumMarkers", b"")
    rate = number(info.get(b"DataRate") or info.get(b"CameraRate") or b"")
    if not (nf.isdigit() and nm.isdigit() and int(nf) >= 1 and int(nm) >= 1) or rate is None or not 0 < rate <= MAX_FPS:
        raise Reject(3, "bad NumFrames, NumMarkers or DataRate")
    units = info.get(b"Units", b"mm").decode("latin-1").lower()
    if units not in TRC_UNITS:
        raise Reject(3, "bad Units")
    n_frames, n_markers = int(nf), int(nm)
    labels = [lb.strip(_SPACE) for lb in head[3].split(b"\t")[2:] if lb.strip(_SPACE)]
    if len(labels) != n_markers and b"\t" not in head[3]:
        labels = _header_words(head[3])[2:]
    if len(labels) > n_markers or not labels:
        raise Reject(4, "label count differs from NumMarkers")
    width = 2 + 3 * n_markers
    rows = []
    data_lines = [k for k in range(5, len(lines)) if lines[k].split()]
    body = data.replace(b"\r\r\n", b"\r\n")
    n_bytes = len(body) - (3 if body.startswith(b"\xef\xbb\xbf") else 0)
    if len(data_lines) * width > 2 * n_bytes + 4096:  # a field costs at least its separator
        raise Reject(3, "NumMarkers too large for the file")
    labels += [b"point%d" % (k + 1) for k in range(len(labels), n_markers)]
    for k in data_lines:
        line = lines[k]
        words = line.split()
        vals = numbers(words) if len(words) == width else None
        if vals is None:
            vals = _trc_fields(line, words, width, k, k == data_lines[-1])
        frame, time = vals[0], vals[1]
        if not (
            math.isfinite(frame)
            and math.isfinite(time)
            and abs(frame) < 1e9
            and frame == int(frame)
            and abs(time) < 1e9
        ):
            raise Reject(k + 1, "bad frame number or time")
        rows.append(vals)
    if not 0 < len(rows) <= n_frames:  # fewer complete rows than NumFrames: the rows are read
        raise Reject(len(lines), "row count differs from NumFrames")
    n_frames = len(rows)
    table = np.array(rows)
    pos = table[:, 2:].reshape(n_frames, n_markers, 3) * TRC_UNITS[units]
    if (np.abs(pos) > MAX_METRES).any():
        raise Reject(6, "marker out of bounds")
    pos[np.isnan(pos).any(-1)] = np.nan
    return {
        "labels": tuple(lb.decode("latin-1") for lb in labels),
        "rate": rate,
        "first_frame": int(table[0, 0]),
        "positions": pos,
    }
