"""Fast whitespace tokenizer and float parser for text motion files (AMC, TRC; BVH tables: ``_bvh_rows``).

This is a kernel module: no validation, no error messages. It imports numba at module
level, so the readers import it lazily (never at CLI start-up). The slow, obviously
correct twin is ``tests/naive/formats.py``.

One pass over the bytes yields, per whitespace-separated token: its byte offset, length,
1-based line number, whether it is a finite decimal number and its value, and for
non-numbers a 64-bit FNV-1a hash (to compare name tokens without building Python
strings; 0 for numbers). Lines end at LF;
CR is whitespace, so CRLF, LF and files mixing both count lines alike.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_FNV_OFFSET = np.uint64(14695981039346656037)
_FNV_PRIME = np.uint64(1099511628211)
#: Exact powers of ten representable in a double (10**0 .. 10**22).
_POW10 = np.array([10.0**k for k in range(23)])


def fnv1a(token: bytes) -> int:
    """The token hash of :func:`tokenize`, computed in Python for expected names."""
    h = 14695981039346656037
    for c in token:
        h = ((h ^ c) * 1099511628211) & 0xFFFFFFFFFFFFFFFF
    return h


@njit(cache=True)
def _parse_number(buf: np.ndarray, s: int, e: int, pow10: np.ndarray) -> tuple[bool, float, int]:
    """Parse the decimal number starting at ``buf[s]`` (not beyond ``e``).

    Returns (ok, value, j): ``j`` is where the number's characters end; ``ok`` says that
    they form a complete finite number (the caller checks that a token ends at ``j``).
    """
    j = s
    neg = False
    c = buf[j]
    if c == 45 or c == 43:  # - +
        neg = c == 45
        j += 1
    mant = np.int64(0)
    nd = 0
    exp10 = 0
    digits = False
    while j < e and 48 <= buf[j] <= 57:
        d = buf[j] - 48
        digits = True
        if nd < 18:
            mant = mant * 10 + d
            if mant != 0:
                nd += 1
        else:
            exp10 += 1
        j += 1
    if j < e and buf[j] == 46:  # .
        j += 1
        while j < e and 48 <= buf[j] <= 57:
            d = buf[j] - 48
            digits = True
            if nd < 18:
                mant = mant * 10 + d
                if mant != 0:
                    nd += 1
                exp10 -= 1
            j += 1
    if not digits:
        return False, 0.0, j
    if j < e and (buf[j] == 101 or buf[j] == 69):  # e E
        j += 1
        eneg = False
        if j < e and (buf[j] == 45 or buf[j] == 43):
            eneg = buf[j] == 45
            j += 1
        if j >= e or not 48 <= buf[j] <= 57:
            return False, 0.0, j
        ex = 0
        while j < e and 48 <= buf[j] <= 57:
            if ex < 100000:
                ex = ex * 10 + (buf[j] - 48)
            j += 1
        exp10 += -ex if eneg else ex
    v = float(mant)
    # exact mantissa (< 2**53) times an exact power of ten: one correctly rounded operation
    if mant == 0:
        pass  # 0e999 is zero, not 0 * inf
    elif exp10 >= 0:
        v = v * pow10[exp10] if exp10 <= 22 else v * 10.0**exp10
    else:
        if exp10 >= -22:
            v = v / pow10[-exp10]
        else:  # in steps, so that 1e-320 is the subnormal it is, not 1 / inf = 0
            k = -exp10
            while k > 0 and v != 0.0:
                step = min(k, 300)
                v = v / 10.0**step
                k -= step
    if not np.isfinite(v):
        return False, 0.0, j
    return True, -v if neg else v, j


@njit(cache=True)
def _tokenize(
    buf: np.ndarray, start: int, first_line: int, pow10: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, int]:
    n = buf.size
    cap = (n - start) // 2 + 1
    starts = np.empty(cap, np.int64)
    lens = np.empty(cap, np.int64)
    lines = np.empty(cap, np.int64)
    hashes = np.empty(cap, np.uint64)
    values = np.empty(cap, np.float64)
    isnum = np.empty(cap, np.bool_)
    line = first_line
    bad = -1
    k = 0
    i = start
    while i < n:
        c = buf[i]
        if c == 10:
            line += 1
            i += 1
            continue
        if c == 32 or c == 9 or c == 13 or c == 11 or c == 12:
            i += 1
            continue
        if c < 32 or c == 127:
            bad = i
            break
        s = i
        # parse a number while scanning; only a token that is not one is scanned again
        ok, v, i = _parse_number(buf, s, n, pow10)
        if i < n and not (buf[i] <= 32 or buf[i] == 127):
            ok = False
            while i < n:
                c = buf[i]
                if c <= 32 or c == 127:
                    break
                i += 1
        starts[k] = s
        lens[k] = i - s
        lines[k] = line
        isnum[k] = ok
        values[k] = v if ok else np.nan
        h = np.uint64(0)
        if not ok:  # names are compared by hash; numbers never are
            h = np.uint64(14695981039346656037)
            for m in range(s, i):
                h = (h ^ np.uint64(buf[m])) * np.uint64(1099511628211)
        hashes[k] = h
        k += 1
    return starts[:k], lens[:k], lines[:k], hashes[:k], values[:k], isnum[:k], bad, line


def tokenize(
    buf: np.ndarray, start: int = 0, first_line: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, int]:
    """Tokens of the file's bytes ``buf[start:]`` (uint8), ``first_line`` the 1-based line of
    ``start``. Returns per token (n_tokens,): ``starts, lens, lines`` int64, ``hashes`` uint64
    (FNV-1a of non-numeric tokens, 0 for numbers), ``values`` float64 (NaN unless a finite
    decimal), ``isnum`` bool; then ``bad``, the byte offset of the first non-whitespace
    control character (binary garbage; tokenizing stops there) or -1, and ``bad_line``, the
    line reached (that of ``bad`` when ``bad >= 0``)."""
    return _tokenize(buf, start, first_line, _POW10)
