"""The NumPy C3D parser on small files built here for each layout of the C3D specification
(Intel / DEC / SGI-MIPS, int16 scaled / float32, analog channels, headers that contradict the
data), against the values written; the c3d.org sample sets where present
(``MOCAPFLOW_C3D_CORPUS``: the folder ``benchmarks/c3d_peers.py`` reads)."""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np
import pytest

from mocapflow.framework.errors import ParseError
from mocapflow.plugins.formats._c3d_parse import dec_to_float, parse_c3d
from mocapflow.plugins.formats.c3d import read_c3d

PROC = {"intel": 84, "dec": 85, "mips": 86}


def _ints(v, proc: str) -> bytes:
    """16-bit words (negative values as two's complement, counts up to 65535)."""
    return np.asarray(v, np.float64).astype(np.int64).astype(">u2" if proc == "mips" else "<u2").tobytes()


def _floats(v, proc: str) -> bytes:
    a = np.asarray(v, np.float32)
    if proc == "mips":
        return a.astype(">f4").tobytes()
    if proc == "intel":
        return a.astype("<f4").tobytes()
    b = np.frombuffer((a * np.float32(4)).astype("<f4").tobytes(), np.uint8).reshape(-1, 4)
    return b[:, [2, 3, 0, 1]].tobytes()  # VAX F: value x 4, 16-bit halves swapped


def _param(gid: int, name: str, kind: int, dims: tuple[int, ...], data: bytes, proc: str, last: bool) -> bytes:
    body = struct.pack("bB", kind, len(dims)) + bytes(dims) + data + b"\x00"
    off = 0 if last else 2 + len(body)
    return struct.pack("bb", len(name), gid) + name.encode() + _ints([off], proc) + body


def make_c3d(
    points: np.ndarray,
    resid: np.ndarray,
    proc: str = "intel",
    float_data: bool = True,
    scale: float = 0.1,
    rate: float = 100.0,
    analog: np.ndarray | None = None,
    per: int = 1,
    frames: tuple[int, int] | None = None,
    point_frames: int | None = None,
    header_analog: int | None = None,
    point_used: int | None = None,
    header_scale: float | None = None,
    labels: tuple[str, ...] | None = None,
) -> bytes:
    """A C3D file (mm) holding ``points`` (T, M, 3) with residual words ``resid`` (T, M; < 0:
    invalid) and ``analog`` (T * per, channels) raw samples."""
    t, m = points.shape[:2]
    n_an = 0 if analog is None else analog.shape[1]
    labels = labels or tuple(f"M{k}" for k in range(m))
    s = -abs(scale) if float_data else abs(scale)
    f = _floats
    entries = [
        struct.pack("bb", 5, -1) + b"POINT" + _ints([3], proc) + b"\x00",
        struct.pack("bb", 6, -2) + b"ANALOG" + _ints([3], proc) + b"\x00",
        ("USED", 2, (), _ints([m if point_used is None else point_used], proc)),
        ("SCALE", 4, (), f([s], proc)),
        ("RATE", 4, (), f([rate], proc)),
        ("FRAMES", 2, (), _ints([t if point_frames is None else point_frames], proc)),
        ("UNITS", -1, (2,), b"mm"),
        ("LABELS", -1, (4, m), b"".join(lb.ljust(4).encode()[:4] for lb in labels)),
    ]
    params = b""
    for e in entries:
        if isinstance(e, bytes):
            params += e
        else:
            params += _param(1, e[0], e[1], e[2], e[3], proc, False)
    params += _param(2, "USED", 2, (), _ints([n_an], proc), proc, False)
    params += _param(2, "RATE", 4, (), f([rate * per], proc), proc, True)
    sec = bytes([1, 0x50, 1, PROC[proc]]) + params
    assert len(sec) <= 512
    sec = sec.ljust(512, b"\x00")
    first, last = frames or (1, t)
    hs = s if header_scale is None else header_scale
    head = bytes([2, 0x50]) + _ints([m, n_an * per if header_analog is None else header_analog, first, last, 0], proc)
    head += f([hs], proc) + _ints([3, per], proc) + f([rate], proc)
    head = head.ljust(512, b"\x00")
    rows = []
    for i in range(t):
        if float_data:
            w = np.concatenate([points[i], resid[i][:, None]], axis=1).ravel()
            row = f(w, proc) + (f(analog[i * per : (i + 1) * per].ravel(), proc) if n_an else b"")
        else:
            xyz = np.round(points[i] / scale)
            w = np.concatenate([xyz, resid[i][:, None]], axis=1).ravel()
            row = _ints(w, proc) + (_ints(analog[i * per : (i + 1) * per].ravel(), proc) if n_an else b"")
        rows.append(row)
    data = b"".join(rows)
    return head + sec + data.ljust(-(-len(data) // 512) * 512, b"\x00")


def walk(t: int = 20, m: int = 3, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    pts = 1000.0 + np.cumsum(rng.normal(0, 2, (t, m, 3)), axis=0)  # mm, a smooth walk
    resid = np.full((t, m), 3.0)
    resid[2, 1] = -1.0  # one invalid sample
    return pts, resid


def expected(pts: np.ndarray, resid: np.ndarray, float_data: bool, scale: float = 0.1) -> np.ndarray:
    v = pts.astype(np.float32).astype(np.float64) if float_data else np.round(pts / scale) * float(np.float32(scale))
    v = v / 1000.0
    v[resid < 0] = np.nan
    return v


@pytest.mark.parametrize("proc", ["intel", "dec", "mips"])
@pytest.mark.parametrize("float_data", [True, False])
def test_every_processor_and_word(tmp_path: Path, proc: str, float_data: bool) -> None:
    pts, resid = walk()
    analog = np.arange(20 * 2 * 2, dtype=np.float64).reshape(40, 2)
    p = tmp_path / "a.c3d"
    p.write_bytes(make_c3d(pts, resid, proc, float_data, analog=analog, per=2))
    m = read_c3d(p)
    np.testing.assert_allclose(m.positions, expected(pts, resid, float_data), rtol=0, atol=1e-9, equal_nan=True)
    assert m.labels == ("M0", "M1", "M2") and m.fps == 100.0 and m.metadata["warnings"] == []
    assert m.metadata["processor"] == proc and m.metadata["analog_channels"] == 2
    assert m.metadata["analog_rate"] == 200.0
    np.testing.assert_array_equal(parse_c3d(p.read_bytes()).read_analog(20), analog)


def test_dec_float_twin() -> None:
    """VAX F decoding against a per-value twin written from the format's definition:
    sign, 8-bit exponent (bias 128), 23-bit fraction with a hidden 0.1 bit."""
    rng = np.random.default_rng(1)
    vals = np.concatenate([rng.normal(0, 1e3, 200), [0.0, 1.0, -1.0, 0.5, 1e-30, -3e30]]).astype(np.float32)
    raw = np.frombuffer(_floats(vals, "dec"), np.uint8).reshape(-1, 4)

    def slow(b: np.ndarray) -> float:
        word = int(b[1]) << 24 | int(b[0]) << 16 | int(b[3]) << 8 | int(b[2])
        sign, exp, frac = word >> 31, (word >> 23) & 0xFF, word & 0x7FFFFF
        if exp == 0:
            return 0.0
        return (-1.0) ** sign * (0.5 + frac / 2.0**24) * 2.0 ** (exp - 128)

    want = np.array([slow(b) for b in raw])
    np.testing.assert_array_equal(dec_to_float(raw).astype(np.float64), want)
    np.testing.assert_allclose(want, vals.astype(np.float64), rtol=1e-7)


def test_header_frames_disagree(tmp_path: Path) -> None:
    """The Optotrak case: header 1..1149 and POINT:FRAMES 1149, the file holds 29 frames:
    the 29 are read with a warning naming both counts; ``strict`` refuses."""
    pts, resid = walk(29)
    p = tmp_path / "o.c3d"
    p.write_bytes(make_c3d(pts, resid, frames=(1, 1149), point_frames=1149))
    m = read_c3d(p)
    assert m.n_frames == 29 and "announces 1149 frames" in m.metadata["warnings"][0]
    np.testing.assert_allclose(m.positions, expected(pts, resid, True), atol=1e-9, equal_nan=True)
    with pytest.raises(ParseError, match="truncated C3D"):
        read_c3d(p, strict=True)


def test_frame_fields_that_cannot_count(tmp_path: Path) -> None:
    """Takes over 65,535 frames: the header's 16-bit last frame is 65535 (or wraps below the
    first); POINT:FRAMES counts them, else the whole frames held are read with a warning."""
    pts, resid = walk(12)
    p = tmp_path / "long.c3d"
    p.write_bytes(make_c3d(pts, resid, frames=(1, 65535), point_frames=12))
    m = read_c3d(p)
    assert m.n_frames == 12 and m.metadata["warnings"] == []
    p.write_bytes(make_c3d(pts, resid, frames=(9, 3), point_frames=0))
    m = read_c3d(p)
    assert m.n_frames == 12 and "count no frames" in m.metadata["warnings"][0]
    np.testing.assert_allclose(m.positions, expected(pts, resid, True), atol=1e-9, equal_nan=True)
    with pytest.raises(ParseError, match="expected at least one frame"):
        read_c3d(p, strict=True)


def test_analog_only_names_the_channels(tmp_path: Path) -> None:
    pts = np.zeros((10, 0, 3))
    p = tmp_path / "emg.c3d"
    p.write_bytes(make_c3d(pts, np.zeros((10, 0)), analog=np.zeros((40, 3)), per=4))
    with pytest.raises(ParseError, match=r"only 3 analog channels at 400 Hz") as e:
        read_c3d(p)
    assert "Error" not in str(e.value)


def test_header_analog_word_holds_channels_only(tmp_path: Path) -> None:
    """MotionMonitor writes the channel count, not channels x samples, in header word 3:
    the parameters' layout fills the data section, the header's does not."""
    pts, resid = walk()
    analog = np.ones((20 * 7, 4))
    p = tmp_path / "mm.c3d"
    p.write_bytes(make_c3d(pts, resid, analog=analog, per=7, header_analog=4))
    m = read_c3d(p)
    np.testing.assert_allclose(m.positions, expected(pts, resid, True), atol=1e-9, equal_nan=True)
    assert "parameters' (3 points, 28 analog words)" in m.metadata["warnings"][0]


def test_point_used_above_the_data(tmp_path: Path) -> None:
    """Kyowa Dengyo: POINT:USED one above the header's count; the header fits the data."""
    pts, resid = walk(m=3)
    p = tmp_path / "k.c3d"
    p.write_bytes(make_c3d(pts, resid, proc="dec", float_data=False, point_used=4, labels=("A", "B", "C", "D")))
    m = read_c3d(p)
    np.testing.assert_allclose(m.positions, expected(pts, resid, False), atol=1e-9, equal_nan=True)
    assert m.labels == ("A", "B", "C") and "POINT:USED says 4" in m.metadata["warnings"][0]


def test_scale_disagreement_uses_the_header(tmp_path: Path) -> None:
    pts, resid = walk()
    p = tmp_path / "s.c3d"
    data = make_c3d(pts, resid, float_data=False, scale=0.1)
    p.write_bytes(data)
    good = read_c3d(p)
    # POINT:SCALE rewritten to 0.04: the header's 0.1 is what the data were written with
    i = data.index(b"SCALE", 512)
    at = i + 5 + 2 + 2
    p.write_bytes(data[:at] + _floats([0.04], "intel") + data[at + 4 :])
    m = read_c3d(p)
    np.testing.assert_array_equal(m.positions, good.positions)
    assert "POINT:SCALE 0.04 disagrees" in m.metadata["warnings"][0]


def test_hostile_parameter_sections(tmp_path: Path) -> None:
    """Offsets that point backwards or past the section, entries that overrun it, a
    parameter block past the end: a ParseError or a read with a warning, never a hang or a
    foreign exception."""
    pts, resid = walk()
    data = bytearray(make_c3d(pts, resid))
    p = tmp_path / "h.c3d"
    i = data.index(b"RATE", 512)
    for off in (-30, -2, 0x7FFF):  # the RATE parameter's offset word
        data[i + 4 : i + 6] = struct.pack("<h", off)
        p.write_bytes(bytes(data))
        try:
            read_c3d(p)
        except ParseError as exc:
            assert "Error" not in str(exc)
    p.write_bytes(bytes([200, 0x50]) + bytes(data[2:]))
    with pytest.raises(ParseError, match="past the end"):
        read_c3d(p)


CORPUS = Path(os.environ.get("MOCAPFLOW_C3D_CORPUS", "/nonexistent"))


@pytest.mark.parametrize(
    "folder, names",
    [
        ("sample_01", ("Eb015pi", "Eb015pr", "Eb015si", "Eb015sr", "Eb015vi", "Eb015vr")),
        ("sample_02", ("pc_int", "pc_real", "dec_int", "dec_real", "sgi_int", "sgi_real")),
    ],
)
def test_c3d_org_format_variants_read_alike(folder: str, names: tuple[str, ...]) -> None:
    """c3d.org's sample sets: one capture in each processor format, int and float."""
    root = CORPUS / "biomechanics-foundation__c3dio" / "tests" / "c3d_org_samples" / folder
    if not root.is_dir():
        pytest.skip(f"C3D corpus not found at {root} (set MOCAPFLOW_C3D_CORPUS; benchmarks/c3d_peers.py)")
    reads = [read_c3d(root / f"{n}.c3d") for n in names]
    ref = reads[0]
    for n, m in zip(names, reads, strict=True):
        assert m.labels == ref.labels and m.fps == ref.fps, n
        # int files hold the float files' values rounded to POINT:SCALE
        np.testing.assert_allclose(m.positions, ref.positions, atol=1e-3, equal_nan=True, err_msg=n)
