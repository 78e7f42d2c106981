"""Format kernels against their naive twins (tests/naive/formats.py)."""

from __future__ import annotations

import numpy as np
import pytest
from naive.formats import euler_table_to_quat as naive_euler
from naive.formats import tokenize as naive_tokenize

from mocapflow.framework import quaternions as quat
from mocapflow.framework.quaternions import euler_extrinsic, euler_extrinsic_inverse
from mocapflow.plugins.formats._kernels import euler_table_to_quat
from mocapflow.plugins.formats._text_kernels import fnv1a, tokenize

CASES = [
    b"",
    b"1\n",
    b"root 1 2 3\r\nlfemur -1.5e-3 +2. .5\n2\nx 1e5 -0 00012 1E-015\r\n",
    b"\n\n  \t a  b\r\n\r\n 3.64024e-015 -6.75868e-015 12345678901234567890 0.000000000000000000001234\n",
    b"nan inf -inf 1e400 1.2.3 - + . e5 1e 1e+ 0x10 1_000 ab12 12ab 1e-400",
    b"   trailing 7",
    b"0e999 -0e400 0.0e99999 1e-320 4.9e-324 123456789012345678e-340 1e308 1e309 3",  # DBL_MAX itself may round to inf: refused either way
]


@pytest.mark.parametrize("data", CASES)
def test_tokenize_matches_naive(data: bytes) -> None:
    starts, lens, lines, hashes, values, isnum, bad, _ = tokenize(np.frombuffer(data, np.uint8), 0, 1)
    n_starts, n_lens, n_lines, n_values, n_isnum = naive_tokenize(data)
    assert bad == -1
    np.testing.assert_array_equal(starts, n_starts)
    np.testing.assert_array_equal(lens, n_lens)
    np.testing.assert_array_equal(lines, n_lines)
    np.testing.assert_array_equal(isnum, n_isnum)
    np.testing.assert_allclose(values[isnum], n_values[n_isnum], rtol=1e-15, atol=0)
    assert [int(h) for h in hashes] == [
        0 if num else fnv1a(data[s : s + k]) for s, k, num in zip(starts, lens, isnum, strict=True)
    ]


def test_tokenize_random_numbers_exact() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(scale=100, size=2000) * 10.0 ** rng.integers(-12, 12, size=2000)
    data = ("\n".join(f"{v:.6g} {v:.10g}" for v in x)).encode()
    _s, _l, lines, _h, values, isnum, bad, _ = tokenize(np.frombuffer(data, np.uint8), 0, 5)
    assert bad == -1 and isnum.all() and lines[0] == 5 and lines[-1] == 5 + len(x) - 1
    ref = naive_tokenize(data)[3]
    np.testing.assert_array_equal(values, ref)  # correctly rounded for <= 17 significant digits


def test_tokenize_reports_binary_byte() -> None:
    data = b"1 2\n3 \x00 4\n"
    *_, bad, bad_line = tokenize(np.frombuffer(data, np.uint8), 0, 1)
    assert bad == data.index(b"\x00") and bad_line == 2


def test_tokenize_offset_start() -> None:
    data = b"header\nline two\n1 2 3\n"
    start = data.index(b"1")
    starts, *_ = tokenize(np.frombuffer(data, np.uint8), start, 3)
    assert starts[0] == start


@pytest.mark.parametrize("extrinsic", [True, False])
@pytest.mark.parametrize("t", [1, 7])
def test_euler_kernel_matches_naive(extrinsic: bool, t: int) -> None:
    rng = np.random.default_rng(t)
    nj = 5
    table = rng.uniform(-200, 200, size=(t, 9))
    cols = np.array([[0, 1, 2], [3, -1, -1], [4, 5, -1], [-1, -1, -1], [8, 7, 6]])
    axis_id = np.array([[0, 1, 2], [1, 0, 0], [2, 0, 0], [0, 0, 0], [2, 0, 1]])
    frames = quat.normalize(rng.normal(size=(nj, 4)))
    got = euler_table_to_quat(table, cols, axis_id, frames, np.pi / 180, extrinsic)
    want = naive_euler(table, cols, axis_id, frames, np.pi / 180, extrinsic)
    np.testing.assert_allclose(got, want, atol=1e-12)


@pytest.mark.parametrize("order", ["xyz", "zyx", "yzx", "xz", "zx", "y", "zy"])
def test_euler_extrinsic_inverse_round_trip(order: str) -> None:
    rng = np.random.default_rng(len(order))
    ang = rng.uniform(-80, 80, size=(50, len(order)))
    q = euler_extrinsic(ang, order, degrees=True)
    back = euler_extrinsic_inverse(q, order, degrees=True)
    np.testing.assert_allclose(back, ang, atol=1e-9)
    # extrinsic listed order == intrinsic reversed order (R = R3 R2 R1)
    mats = [quat.from_euler(ang[:, [k]], order[k]) for k in range(len(order))]
    want = mats[0]
    for m in mats[1:]:
        want = quat.mul(m, want)
    np.testing.assert_allclose(np.abs((q * want).sum(-1)), 1.0, atol=1e-12)
