"""A C3D parser in NumPy: header, parameter section, point and analog data.

Layout (the C3D specification, c3d.org "The C3D File Format User Guide"): a file is a
sequence of 512-byte blocks. Block 1 is the header (16-bit words: word 1 holds the first
parameter block and the key 0x50, word 2 the points per frame, word 3 the analog samples
per frame over all channels, words 4-5 the first and last frame, words 7-8 the point scale
as a float (negative: float data), word 9 the first data block, word 10 the analog samples
per point frame, words 11-12 the point rate). The parameter section starts with 4 bytes
(byte 3: processor, 84 Intel, 85 DEC, 86 SGI/MIPS), then groups (negative id) and
parameters (positive id: the group they belong to), each with a name, a signed 16-bit
offset to the next entry, and for parameters a type (-1 char, 1 byte, 2 int16, 4 float),
dimensions and data. A frame holds 4 words per point (x, y, z and a residual word whose
sign marks an invalid sample; its low byte is the residual in units of ``POINT:SCALE``,
its high byte the camera mask), then the analog samples, int16 scaled by ``POINT:SCALE``
or float32 in the processor's format: Intel little-endian IEEE, SGI/MIPS big-endian IEEE,
DEC little-endian integers and VAX F floats (16-bit halves swapped, value / 4).

Everything is bounded by the file's own size: the parameter section must lie in the file,
each entry's data inside the section, a walk over entries stops at the section's end or at
an offset that does not move forward (with a warning), and the data section is read as the
whole frames the file holds. Nothing here raises anything but :class:`C3dError`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, cast

import numpy as np

__all__ = ["C3dError", "C3dFile", "Param", "parse_c3d"]

BLOCK = 512
PROCESSORS = {84: "intel", 85: "dec", 86: "mips"}
#: Entries (groups + parameters) a parameter section may hold: real files hold < 2,000.
MAX_ENTRIES = 1 << 16


class C3dError(Exception):
    """A file that does not follow the C3D layout (the reader turns it into a ParseError)."""


def dec_to_float(raw: np.ndarray) -> np.ndarray:
    """VAX F floats (bytes as stored, shape (..., 4) uint8) -> float32: swap the 16-bit
    halves, read as little-endian IEEE, divide by 4 (VAX's exponent bias is 128 and its
    hidden bit sits at 0.5); a zero exponent is 0 in VAX."""
    b = np.ascontiguousarray(raw.reshape(-1, 4)[:, [2, 3, 0, 1]])
    v = b.view("<f4").reshape(raw.shape[:-1])
    bits = b.view("<u4").reshape(raw.shape[:-1])
    with np.errstate(over="ignore", invalid="ignore"):
        return cast("np.ndarray", np.where((bits & 0x7F800000) == 0, np.float32(0), v / np.float32(4)))


@dataclass
class Param:
    """One parameter: ``kind`` -1 char, 1 byte, 2 int16, 4 float; ``dims`` as in the file
    (first dimension varies fastest); ``data`` its raw bytes."""

    group: str
    name: str
    kind: int
    dims: tuple[int, ...]
    data: bytes
    processor: str

    def numbers(self) -> np.ndarray:
        """The values as float64 (flat, file order); chars give their byte values."""
        if self.kind == 4:
            raw = np.frombuffer(self.data, np.uint8)
            if self.processor == "dec":
                return dec_to_float(raw.reshape(-1, 4)).astype(np.float64)
            return np.frombuffer(self.data, ">f4" if self.processor == "mips" else "<f4").astype(np.float64)
        if self.kind == 2:
            return np.frombuffer(self.data, ">i2" if self.processor == "mips" else "<i2").astype(np.float64)
        if self.kind == 1:
            return np.frombuffer(self.data, np.int8).astype(np.float64)
        return np.frombuffer(self.data, np.uint8).astype(np.float64)

    def uint16(self) -> np.ndarray:
        """Integer values read as unsigned 16-bit (counts above 32,767 in int16 parameters)."""
        if self.kind == 2:
            return np.frombuffer(self.data, ">u2" if self.processor == "mips" else "<u2").astype(np.int64)
        return self.numbers().astype(np.int64)

    def scalar(self) -> float | None:
        v = self.numbers()
        return float(v[0]) if self.kind in (1, 2, 4) and len(v) else None

    def strings(self) -> list[str]:
        """A char parameter as strings: the first dimension is the length of each, padding
        (spaces, NUL) stripped; a scalar or 1-D char parameter is one string."""
        text = self.data.decode("latin-1")
        if self.kind != -1:
            return []
        if len(self.dims) <= 1:
            return [text.strip(" \t\r\n\x00")]
        n = self.dims[0]
        count = len(text) // n if n else 0
        return [text[k * n : (k + 1) * n].strip(" \t\r\n\x00") for k in range(count)]


@dataclass
class C3dFile:
    """A parsed C3D file: header words, parameters by ``"GROUP:NAME"`` (upper case), and
    the byte layout of its frames. ``warnings`` lists what the parser repaired."""

    data: bytes
    processor: str
    header_points: int
    header_analog: int
    first_frame: int
    last_frame: int
    header_scale: float
    data_block: int
    header_analog_per_frame: int
    header_rate: float
    params: dict[str, Param]
    warnings: list[str] = field(default_factory=list)
    #: points per frame and analog words per frame the data follow (see :func:`_layout`)
    n_points: int = -1
    analog_words: int = -1

    # -- parameters ----------------------------------------------------------------------
    def get(self, key: str) -> Param | None:
        return self.params.get(key.upper())

    def number(self, key: str) -> float | None:
        p = self.get(key)
        return None if p is None else p.scalar()

    def string(self, key: str) -> str | None:
        p = self.get(key)
        if p is None or p.kind != -1:
            return None
        s = p.strings()
        return s[0] if s else ""

    def labels(self, group: str, count: int) -> list[str]:
        """``GROUP:LABELS``, ``LABELS2``, ``LABELS3``... concatenated (files with more than
        255 points or channels continue the list there), the first ``count``."""
        out: list[str] = []
        for k in range(1, 100):
            p = self.get(f"{group}:LABELS" + ("" if k == 1 else str(k)))
            if p is None:
                break
            out += p.strings() if len(p.dims) > 1 else ([p.strings()[0]] if p.data else [])
            if len(out) >= count:
                break
        return out[:count]

    # -- layout --------------------------------------------------------------------------
    @property
    def float_data(self) -> bool:
        return self.point_scale < 0

    @property
    def point_scale(self) -> float:
        """``POINT:SCALE``; the header's word when the two disagree in an integer file (the
        header is what the data were written with: in the one such file seen, c3d.org's
        MACsample, the header's scale gives a 1.46 m shoulder marker and a 1.23 m/s walk,
        ``POINT:SCALE`` a 0.57 m shoulder)."""
        v = self.number("POINT:SCALE")
        h = self.header_scale
        if v is None or not np.isfinite(v) or v == 0:
            return h
        if v > 0 and np.isfinite(h) and h > 0 and not np.isclose(v, h, rtol=1e-5):
            return h
        return v

    @property
    def points(self) -> int:
        """Points per frame (the header's count unless the data prove ``POINT:USED``)."""
        return self.header_points if self.n_points < 0 else self.n_points

    @property
    def point_rate(self) -> float:
        v = self.number("POINT:RATE")
        return v if v is not None and np.isfinite(v) and v > 0 else self.header_rate

    @property
    def n_analog(self) -> int:
        """Analog words per frame (all channels, all samples)."""
        return self.header_analog if self.analog_words < 0 else self.analog_words

    def analog_used(self) -> int:
        """``ANALOG:USED`` (0 when absent)."""
        p = self.get("ANALOG:USED")
        return int(p.uint16()[0]) if p is not None and len(p.data) >= 1 and p.kind in (1, 2) else 0

    @property
    def analog_per_frame(self) -> int:
        """Samples of each analog channel per point frame (0 without analog data)."""
        if self.n_analog == 0:
            return 0
        used = self.analog_channels
        return self.n_analog // used if used else 0

    @property
    def analog_channels(self) -> int:
        if self.n_analog == 0:
            return 0
        used = self.analog_used()
        if (used <= 0 or self.n_analog % used) and self.header_analog_per_frame > 0:
            used = self.n_analog // self.header_analog_per_frame
        return used

    @property
    def word(self) -> int:
        return 4 if self.float_data else 2

    @property
    def frame_bytes(self) -> int:
        return self.word * (4 * self.points + self.n_analog)

    @property
    def data_start(self) -> int:
        return (self.data_block - 1) * BLOCK

    def frames_held(self) -> int:
        """Whole frames the data section holds."""
        if self.frame_bytes == 0:
            return 0
        return max(0, len(self.data) - self.data_start) // self.frame_bytes

    def frames_announced(self) -> int | None:
        """Frames the header announces (last - first + 1), or from ``POINT:FRAMES`` /
        ``TRIAL:ACTUAL_*_FIELD`` when the 16-bit header fields cannot hold the count."""
        n = self.last_frame - self.first_frame + 1
        if self.last_frame == 65535 or n <= 0:
            trial_s, trial_e = self.get("TRIAL:ACTUAL_START_FIELD"), self.get("TRIAL:ACTUAL_END_FIELD")
            if trial_s is not None and trial_e is not None and len(trial_e.data) >= 4:
                s, e = trial_s.uint16(), trial_e.uint16()
                if len(s) >= 2 and len(e) >= 2:
                    return int(e[0] + (e[1] << 16)) - int(s[0] + (s[1] << 16)) + 1
            return self.point_frames()
        return n

    def point_frames(self) -> int | None:
        """``POINT:FRAMES`` (int16 read unsigned, or float), when present and sane."""
        p = self.get("POINT:FRAMES")
        if p is None or not p.data:
            return None
        v = float(p.numbers()[0]) if p.kind == 4 else float(p.uint16()[0])
        return int(v) if 0 < v < 2**31 and v == int(v) else None

    def frame_block(self, frames: int) -> np.ndarray:
        """The first ``frames`` frames as raw bytes, shape (frames, frame_bytes)."""
        return np.frombuffer(self.data, np.uint8, count=frames * self.frame_bytes, offset=self.data_start).reshape(
            frames, self.frame_bytes
        )

    def _words(self, raw: np.ndarray, float_data: bool) -> np.ndarray:
        """Raw bytes (T, n*word) -> values (T, n) float64 in the processor's format."""
        t = raw.shape[0]
        raw = np.ascontiguousarray(raw)
        with np.errstate(invalid="ignore"):  # signalling NaNs stay NaN, quietly
            if float_data:
                if self.processor == "dec":
                    return dec_to_float(raw.reshape(t, -1, 4)).astype(np.float64)
                return raw.view(">f4" if self.processor == "mips" else "<f4").astype(np.float64)
            return raw.view(">i2" if self.processor == "mips" else "<i2").astype(np.float64)

    def read_points(self, frames: int) -> np.ndarray:
        """Points (T, M, 4) in file units: x, y, z and the residual (in units, -1 for an
        invalid sample)."""
        m = self.points
        block = self.frame_block(frames)[:, : 4 * m * self.word]
        vals = self._words(block, self.float_data).reshape(frames, m, 4)
        scale = abs(self.point_scale)
        word = vals[..., 3]
        with np.errstate(invalid="ignore"):
            valid = ~(word < 0)  # compared as a float: a huge positive residual is valid
            low = np.where(valid & (word < 2.0**31), word, 0.0).astype(np.int64) & 0xFF
        if not self.float_data:
            vals[..., :3] *= scale
        vals[..., 3] = np.where(valid, low * scale, -1.0)
        return vals

    def analog_offsets_scales(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Per-channel offset and scale (``(raw - offset) * scale * GEN_SCALE``)."""

        def per_channel(key: str, default: float) -> np.ndarray:
            out: list[float] = []
            for k in range(1, 100):
                p = self.get(key + ("" if k == 1 else str(k)))
                if p is None:
                    break
                out += p.numbers().tolist()
                if len(out) >= n:
                    break
            v = np.full(n, default)
            v[: min(n, len(out))] = out[:n]
            return v

        offset = per_channel("ANALOG:OFFSET", 0.0)
        fmt = (self.string("ANALOG:FORMAT") or "").upper()
        if fmt.startswith("UNSIGNED"):
            offset = np.where(offset < 0, offset + 65536, offset)
        gen = self.number("ANALOG:GEN_SCALE")
        scale = per_channel("ANALOG:SCALE", 1.0) * (gen if gen is not None and np.isfinite(gen) else 1.0)
        return offset, scale

    def read_analog(self, frames: int) -> np.ndarray:
        """Analog samples (T * per_frame, channels), scaled (float64)."""
        n, per = self.analog_channels, self.analog_per_frame
        if n == 0 or per == 0:
            return np.zeros((0, n))
        start = 4 * self.points * self.word
        block = self.frame_block(frames)[:, start : start + n * per * self.word]
        raw = self._words(block, self.float_data).reshape(frames * per, n)
        if not self.float_data and (self.string("ANALOG:FORMAT") or "").upper().startswith("UNSIGNED"):
            raw = np.where(raw < 0, raw + 65536, raw)
        offset, scale = self.analog_offsets_scales(n)
        return cast("np.ndarray", (raw - offset) * scale)


def _u16(b: bytes, off: int, processor: str) -> int:
    return int.from_bytes(b[off : off + 2], "big" if processor == "mips" else "little", signed=False)


def _f32(b: bytes, off: int, processor: str) -> float:
    raw = np.frombuffer(b, np.uint8, count=4, offset=off)
    if processor == "dec":
        return float(dec_to_float(raw.reshape(1, 4))[0])
    return float(raw.view(">f4" if processor == "mips" else "<f4")[0])


def _guess_processor(data: bytes) -> str:
    """A processor byte outside 84-86: the byte order whose header makes sense (first
    frame >= 1, last >= first, a data block after the parameters)."""
    for proc in ("intel", "mips"):
        first, last, block = _u16(data, 6, proc), _u16(data, 8, proc), _u16(data, 16, proc)
        if 1 <= first <= last and block > data[0]:
            return proc
    return "intel"


def _parse_params(data: bytes, start: int, end: int, processor: str, warn: list[str]) -> dict[str, Param]:
    groups: dict[int, str] = {}
    pending: list[tuple[int, str, int, tuple[int, ...], bytes]] = []
    pos = start + 4
    order: Literal["big", "little"] = "big" if processor == "mips" else "little"
    for _ in range(MAX_ENTRIES):
        if pos + 2 > end:
            break
        n_chars = data[pos]
        n_chars = n_chars - 256 if n_chars > 127 else n_chars
        gid = data[pos + 1]
        gid = gid - 256 if gid > 127 else gid
        n_chars = abs(n_chars)  # negative: locked
        if n_chars == 0 or gid == 0:
            break
        name_end = pos + 2 + n_chars
        if name_end + 2 > end:
            warn.append(f"parameter section ends inside an entry at byte {pos}: stopped there")
            break
        name = data[pos + 2 : name_end].decode("latin-1").strip(" \x00").upper()
        off_at = name_end
        offset = int.from_bytes(data[off_at : off_at + 2], order, signed=True)
        body = off_at + 2
        if gid < 0:
            groups[-gid] = name
        else:
            try:
                if body + 2 > end:
                    raise IndexError
                kind = data[body] - 256 if data[body] > 127 else data[body]
                nd = data[body + 1]
                dims = tuple(data[body + 2 : body + 2 + nd])
                if len(dims) != nd or kind not in (-1, 1, 2, 4):
                    raise IndexError
                size = abs(kind) * int(np.prod(dims, dtype=np.int64)) if nd else abs(kind)
                d0 = body + 2 + nd
                if d0 + size > end:
                    raise IndexError
                pending.append((gid, name, kind, dims, data[d0 : d0 + size]))
            except IndexError:
                warn.append(f"parameter {name!r} at byte {pos} does not fit the section: skipped")
        if offset == 0:
            break
        nxt = off_at + offset
        if nxt <= pos or nxt >= end:
            if nxt >= end:
                break
            warn.append(f"parameter offset at byte {off_at} points backwards: stopped reading parameters there")
            break
        pos = nxt
    params: dict[str, Param] = {}
    for gid, name, kind, dims, raw in pending:
        g = groups.get(gid, f"GROUP{gid}")
        params.setdefault(f"{g}:{name}", Param(g, name, kind, dims, raw, processor))
    return params


def _layout(f: C3dFile) -> None:
    """Points and analog words per frame. The header's counts, unless they contradict the
    data section and the parameters (``POINT:USED``; ``ANALOG:USED`` x samples per frame)
    fit it: some writers put the channel count, not channels x samples, in header word 3
    (MotionMonitor), others a ``POINT:USED`` one above the points they write (Kyowa Dengyo:
    the header's count fits the data, ``POINT:USED`` does not). A layout fits when the
    announced frames fill the data section up to its last 512-byte block."""
    announced = f.frames_announced()
    if not announced or announced <= 0:
        return
    used_p = f.get("POINT:USED")
    p_used = int(used_p.uint16()[0]) if used_p is not None and used_p.kind in (1, 2) and used_p.data else -1
    a_used = f.analog_used()
    per = f.header_analog_per_frame
    if per <= 0 and a_used:
        rate, arate = f.point_rate, f.number("ANALOG:RATE")
        if arate is not None and rate > 0 and np.isfinite(arate):
            per = int(round(arate / rate))
    have = max(0, len(f.data) - (f.data_block - 1) * BLOCK)

    def fits(points: int, analog: int) -> bool:
        need = announced * f.word * (4 * points + analog)
        return need <= have < need + BLOCK + f.word * (4 * points + analog)

    header = (f.header_points, f.header_analog)
    if fits(*header):
        if 0 <= p_used != f.header_points:
            f.warnings.append(
                f"POINT:USED says {p_used} points, the header {f.header_points} and the data hold "
                f"{f.header_points}-point frames: read {f.header_points}"
            )
        return
    for cand in ((max(p_used, 0), header[1]), (header[0], a_used * per), (max(p_used, 0), a_used * per)):
        if cand != header and cand[0] >= 0 and cand[1] >= 0 and fits(*cand):
            f.n_points, f.analog_words = cand
            f.warnings.append(
                f"the header's layout ({header[0]} points, {header[1]} analog words a frame) does not fit the "
                f"data section; the parameters' ({cand[0]} points, {cand[1]} analog words) do: read those"
            )
            return


def parse_c3d(data: bytes) -> C3dFile:
    """Header and parameter section of a C3D file (the data are read on demand)."""
    if len(data) < BLOCK:
        raise C3dError(f"expected a 512-byte header, the file holds {len(data)} bytes")
    if data[1] != 0x50:
        raise C3dError("expected a C3D file (byte 2 of the header must be 0x50)")
    pblock = data[0]
    if pblock < 2:
        raise C3dError(f"expected the parameter section in block 2 or later, the header says block {pblock}")
    pstart = (pblock - 1) * BLOCK
    if pstart + 4 > len(data):
        raise C3dError(f"the header puts the parameter section at byte {pstart}, past the end of the file")
    warn: list[str] = []
    processor = PROCESSORS.get(data[pstart + 3])
    if processor is None:
        processor = _guess_processor(data)
        warn.append(f"unknown processor type {data[pstart + 3]} in the parameter section: read as {processor}")
    n_blocks = data[pstart + 2]
    data_block = _u16(data, 16, processor)
    # the section's own block count, or up to the data when that is further (writers that
    # count one block too few: Dance.c3d's POINT:LABELS runs into the next block)
    pend = min(len(data), max(pstart + max(n_blocks, 1) * BLOCK, (data_block - 1) * BLOCK))
    params = _parse_params(data, pstart, pend, processor, warn)
    if warn and not any(k.startswith("POINT:") for k in params):
        # the walk broke off before any POINT parameter: a garbled section, not a file to guess
        raise C3dError(f"expected a parameter section with a POINT group at byte {pstart}; {warn[-1]}")
    f = C3dFile(
        data=data,
        processor=processor,
        header_points=_u16(data, 2, processor),
        header_analog=_u16(data, 4, processor),
        first_frame=_u16(data, 6, processor),
        last_frame=_u16(data, 8, processor),
        header_scale=_f32(data, 12, processor),
        data_block=data_block,
        header_analog_per_frame=_u16(data, 18, processor),
        header_rate=_f32(data, 20, processor),
        params=params,
        warnings=warn,
    )
    if f.data_block < 2:
        ds = f.get("POINT:DATA_START")
        if ds is not None and ds.kind == 2 and ds.data:
            f.data_block = int(ds.uint16()[0])
            warn.append(f"header data block 0: POINT:DATA_START {f.data_block} used")
        if f.data_block < 2:
            raise C3dError(f"expected the data section in block 2 or later, the header says block {data_block}")
    ps = f.number("POINT:SCALE")
    if ps is not None and ps > 0 and f.header_scale > 0 and f.point_scale != ps:
        warn.append(f"POINT:SCALE {ps:g} disagrees with the header's {f.header_scale:g}: the header's used")
    _layout(f)
    return f
