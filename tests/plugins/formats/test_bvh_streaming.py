"""The streaming BVH MOTION parser (:func:`_bvh_rows.parse_rows` over line blocks) gives
the slow tokenizer's values, line by line, and the whole-file parser's errors."""

from __future__ import annotations

import numpy as np
import pytest
from naive.formats import tokenize

from mocapflow.framework.errors import ParseError
from mocapflow.plugins.formats import _stream
from mocapflow.plugins.formats._bvh_rows import parse_rows, table_state
from mocapflow.plugins.formats.bvh import read_bvh


def _reference(body: bytes, cols: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows of numbers and their lines from the slow tokenizer (Python's ``split`` and ``float``)."""
    starts, lens, lines, values, isnum = tokenize(body, 0, 1)
    assert isnum.all()
    uniq = np.unique(lines)
    return values.reshape(len(uniq), cols), uniq


@pytest.mark.parametrize("seed", range(5))
def test_parse_rows_equals_the_slow_tokenizer(seed, monkeypatch):
    from mocapflow.plugins.formats import _bvh_rows

    rng = np.random.default_rng(seed)
    monkeypatch.setattr(_bvh_rows, "PIECE_BYTES", [1, 16, 50, 1 << 20, 7][seed])  # pieces cut at line ends
    rows, cols = 40, 7
    vals = rng.normal(size=(rows, cols)) * 10.0 ** rng.integers(-8, 8, size=(rows, cols))
    text = "\n".join(
        (" " * int(rng.integers(3)))
        + " ".join(np.format_float_positional(v) if rng.random() < 0.5 else f"{v:.17g}" for v in r)
        + ("\r" if rng.random() < 0.2 else "")
        + ("\n" if rng.random() < 0.2 else "")
        for r in vals
    ).encode()
    want, want_lines = _reference(text, cols)
    out, lines, state = np.empty((rows, cols)), np.zeros(rows, np.int64), table_state()
    # in blocks cut at line ends, as the reader feeds it
    line, pos = 1, 0
    while pos < len(text):
        cut = text.find(b"\n", min(pos + int(rng.integers(1, 200)), len(text) - 1))
        cut = len(text) if cut < 0 else cut + 1
        line = parse_rows(text[pos:cut], line, out, lines, state)
        pos = cut
    assert state[0] == rows and state[1] < 0 and state[2] < 0
    assert np.array_equal(out, want) and np.array_equal(lines, want_lines)


BVH = b"""HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  End Site
  {
    OFFSET 0 10 0
  }
}
MOTION
Frames: 3
Frame Time: 0.0333333
"""


@pytest.mark.parametrize(
    ("data", "line", "expected"),
    [
        (b"1 2 3 4 5 6\n1 2 3 4 5\n1 2 3 4 5 6\n", 15, "expected 6 values on this frame line, found 5"),
        (b"1 2 3 4 5 6\n1 2 x 4 5 6\n1 2 3 4 5 6\n", 15, "found a non-number"),
        (b"1 2 3 4 5 6\n", 14, "expected 3 frame lines (Frames:), found 1"),
        (b"\n\n", 13, "after this line, found none"),
        (b"1 2 3 4 5 6\n1 2 3 4 5 6\n1 2 3 4 5 6\n1 2 \x01\n", 17, "binary byte 0x01"),
    ],
)
def test_errors_name_the_line(tmp_path, data, line, expected):
    f = tmp_path / "a.bvh"
    f.write_bytes(BVH + data)
    with pytest.raises(ParseError) as info:
        read_bvh(f)
    assert info.value.line == line and expected in str(info.value), str(info.value)


def test_small_blocks_give_the_same_motion(tmp_path, monkeypatch):
    f = tmp_path / "a.bvh"
    f.write_bytes(BVH.replace(b"Frames: 3", b"Frames: 6000") + b"1 2 3 4 5 6\r\n" * 3000 + b"\n2 3 4 5 6 7\n" * 3000)
    whole = read_bvh(f)
    monkeypatch.setattr(_stream, "BLOCK_BYTES", 7)  # after the first 64 KiB: 7-byte reads
    small = read_bvh(f)
    assert np.array_equal(whole.rotations, small.rotations)
    assert np.array_equal(whole.root_translation, small.root_translation)
    assert whole.metadata == small.metadata


def test_rotations_in_shrinking_blocks_equal_the_whole_table_conversion(monkeypatch):
    """The block-wise, table-shrinking conversion (bounded memory) gives the rotations of one
    conversion of the whole table, for any block size, the table emptied behind it."""
    from mocapflow.framework import quaternions as quat
    from mocapflow.plugins.formats import _bvh_table
    from mocapflow.plugins.formats._kernels import euler_table_to_quat, readonly

    rng = np.random.default_rng(3)
    nj, frames = 4, 37
    table = rng.uniform(-180, 180, size=(frames, 3 + 3 * nj))
    cols = np.array([[3 + 3 * j, 4 + 3 * j, 5 + 3 * j] for j in range(nj)], dtype=np.int64)
    axis = np.array([[2, 0, 1]] * nj, dtype=np.int64)
    whole = euler_table_to_quat(table, cols, axis, readonly(quat.identity((nj,))), np.pi / 180.0, False)
    for block_values in (1, 15, 100, 10_000):
        monkeypatch.setattr(_bvh_table, "TABLE_BLOCK_VALUES", block_values)
        held = [table.copy()]
        got = _bvh_table._rotations(held, cols, axis, nj)
        assert held == []
        np.testing.assert_array_equal(got, whole)


def test_out_of_range_value_in_a_later_block_names_its_line(tmp_path, monkeypatch):
    """The bounds check runs in blocks of rows: the first bad value is still the one named."""
    from mocapflow.framework.errors import ParseError
    from mocapflow.plugins.formats import _bvh_table, bvh

    monkeypatch.setattr(_bvh_table, "TABLE_BLOCK_VALUES", 6)  # one row per block
    rows = ["0 0 0 0 0 0"] * 5 + ["0 0 0 0 1e12 0"] + ["0 0 0 0 0 0"] * 2
    text = (
        "HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n"
        "  End Site\n  {\n    OFFSET 0 1 0\n  }\n}\nMOTION\nFrames: 8\nFrame Time: 0.01\n" + "\n".join(rows) + "\n"
    )
    p = tmp_path / "far.bvh"
    p.write_text(text)
    with pytest.raises(ParseError, match="Xrotation within") as err:
        bvh.read_bvh(p)
    assert err.value.line == 13 + 6


@pytest.mark.parametrize(
    "token",
    [b"nan", b"-inf", b"Infinity", b"1e400", b"0x1A", b"1_0", b"1-2", b"1e", b"--1", b".", b"1.2.3", b"e5", b"x"],
)
def test_parse_rows_refuses_what_the_tokenizer_calls_a_non_number(token):
    """Every token must be one finite decimal number; the first line holding another names the error,
    even after a line of the wrong count and in a later block."""
    out, lines, state = np.empty((4, 3)), np.zeros(4, np.int64), table_state()
    parse_rows(b"1 2 3\n1 2\n", 10, out, lines, state)
    parse_rows(b"\n4 5 6\n7 " + token + b" 9\n1 2 3\n", 12, out, lines, state)
    assert state[2] == 11 and state[3] == 2
    assert state[1] == 14, (token, state)
    slow_ok = tokenize(token)[4]
    assert not slow_ok.all()


def test_parse_rows_values_equal_the_slow_parser_on_hard_numbers():
    """Long mantissas, extreme exponents and subnormals: correctly rounded, as Python's float."""
    rng = np.random.default_rng(7)
    words = [
        "0.1000000000000000055511151231257827",
        "123456789012345678901234567890",
        "1e-320",
        "-4.9e-324",
        "1.7976931348623157e308",
        "+.5",
        "5.",
        "-0",
        "0e999",
        "2.2250738585072011e-308",
    ] + [repr(float(v)) for v in rng.normal(size=30) * 10.0 ** rng.integers(-300, 300, 30)]
    text = "\n".join(" ".join(words[i : i + 5]) for i in range(0, 40, 5)).encode() + b"\n"
    out, lines, state = np.empty((8, 5)), np.zeros(8, np.int64), table_state()
    parse_rows(text, 1, out, lines, state)
    want, want_lines = _reference(text, 5)
    assert state[1] < 0 and state[2] < 0 and state[0] == 8
    assert np.array_equal(out, want) and np.array_equal(lines, want_lines)


def test_euler_rows_equal_the_slow_twin():
    from naive.formats import euler_table_to_quat as naive_euler

    from mocapflow.framework import quaternions as quat
    from mocapflow.plugins.formats._bvh_table import euler_rows_to_quat

    rng = np.random.default_rng(11)
    table = rng.uniform(-720, 720, size=(9, 12))
    cols = np.array([[0, 1, 2], [5, 3, -1], [6, -1, -1], [11, 9, 10]], dtype=np.int64)
    axis = np.array([[2, 0, 1], [0, 1, 2], [1, 0, 0], [2, 1, 0]], dtype=np.int64)
    got = euler_rows_to_quat(table, cols, axis)
    want = naive_euler(table, cols, axis, quat.identity((4,)), np.pi / 180.0, False)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-13)


def test_reading_a_bvh_loads_no_compiled_kernel(tmp_path):
    """numba's import and kernels cost ~130 MB and a first-run compile: a BVH read needs neither."""
    import subprocess
    import sys

    f = tmp_path / "a.bvh"
    f.write_bytes(BVH + b"1 2 3 4 5 6\n" * 3)
    code = (
        f"import sys, mocapflow; m = mocapflow.read({str(f)!r}); assert m.n_frames == 3; print('numba' in sys.modules)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "False", done.stdout + done.stderr
