"""Excerpts of real corpus files and their mutations: the cases of the parser fuzzer
(checked by :mod:`naive.fuzz`; driver ``benchmarks/fuzz_parsers.py``)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Mutation kinds; ``SAME`` ones keep the content (must give identical arrays), ``BREAK``
#: ones must be refused.
KINDS = (
    "truncate",
    "truncate_line",
    "byte_flip",
    "control_byte",
    "nonfinite",
    "number",
    "eol",
    "bom",
    "bom_eol",
    "blanks",
    "wrong_count",
    "dup_line",
    "del_line",
    "swap_lines",
    "dup_bone",
    "undefined_bone",
    "huge_line",
    "header",
)
SAME = {"eol", "bom", "bom_eol", "blanks"}
BREAK = {"dup_bone", "undefined_bone"}
SPECIAL = [
    b"nan",
    b"NaN",
    b"-nan",
    b"inf",
    b"-inf",
    b"Infinity",
    b"1e308",
    b"-1e308",
    b"1e309",
    b"1.7976931348623157e308",
    b"1e-320",
    b"0e999",
    b"1e6",
    b"-3e5",
    b"2e7",
    b"1e400",
    b"1_0",
    b"0x10",
    b"1e",
    b"+-1",
    b".",
    b"-",
    b"1,5",
    b"\xd9\xa1",
    b"\xc2\xb2",
    b"1.5\xa0",
    b"\xa01",
]
CONTROL = [0x00, 0x01, 0x07, 0x08, 0x0B, 0x0C, 0x0E, 0x1B, 0x1F, 0x7F, 0x85, 0xA0, 0xFF]
_NUM = re.compile(rb"(?<![^\s])[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?(?![^\s])")
_FRAME_LINE = re.compile(rb"^[0-9]+\s*$")


@dataclass
class Base:
    """An unmutated case: ``fmt`` (amc, bvh, trc, c3d), file name, bytes, and for AMC the
    ASF bytes and name."""

    fmt: str
    name: str
    data: bytes
    asf: bytes | None = None
    asf_name: str | None = None


# --- sources and excerpts ----------------------------------------------------------------

#: Frames of a source file kept for excerpts (the rest is never used).
SOURCE_FRAMES = 300


def corpus_sources(data_dir: Path, with_c3d: bool) -> dict[str, list[Path]]:
    """Real files per format under ``data_dir`` (../shared/data)."""
    out = {
        "amc": sorted(data_dir.glob("cmu/amc/*/*.amc")) + sorted(data_dir.glob("hdm05/amc/*/*.amc")),
        "bvh": sorted(data_dir.glob("bvh/*/*.bvh")),
        "trc": sorted(data_dir.glob("trc/*/*.trc")),
        "c3d": sorted(p for p in data_dir.glob("c3d/*/*.c3d") if p.stat().st_size < 1_500_000) if with_c3d else [],
    }
    return {k: v for k, v in out.items() if v}


def load_source(fmt: str, path: Path) -> tuple[bytes, bytes | None, str | None]:
    """``(prefix of the file holding its first SOURCE_FRAMES frames, ASF bytes, ASF name)``."""
    data = path.read_bytes()
    if fmt == "amc":
        starts = [m.start() for m in re.finditer(rb"(?m)^[0-9]+\s*$", data[:2_000_000])]
        if len(starts) > SOURCE_FRAMES:
            data = data[: starts[SOURCE_FRAMES]]
        from mocapflow.plugins.formats.asf_amc import find_asf

        asf = find_asf(path)
        return data, asf.read_bytes(), asf.name
    if fmt == "bvh":
        lines = _lines(data)
        m = next(k for k, ln in enumerate(lines) if ln.strip() == b"MOTION")
        return b"".join(lines[: m + 3 + SOURCE_FRAMES]), None, None
    if fmt == "trc":
        return b"".join(_lines(data)[: 6 + SOURCE_FRAMES]), None, None
    return data, None, None


def _lines(data: bytes) -> list[bytes]:
    return data.splitlines(keepends=True)


def excerpt(
    fmt: str, name: str, data: bytes, rng: np.random.Generator, asf: bytes | None = None, asf_name: str | None = None
) -> Base:
    """The first ``n`` frames (``n`` random, 1 to 30) of a real file, from a random start;
    C3D files are used whole."""
    n = int(rng.choice([1, 1, 2, 3, 5, 8, 13, 30]))
    lines = _lines(data)
    if fmt == "amc":
        starts = [k for k, ln in enumerate(lines) if _FRAME_LINE.match(ln)]
        s = int(rng.integers(0, max(1, len(starts) - n))) if rng.random() < 0.5 else 0
        end = starts[s + n] if s + n < len(starts) else len(lines)
        data = b"".join(lines[: starts[0]] + lines[starts[s] : end])
    elif fmt == "bvh":
        m = next(k for k, ln in enumerate(lines) if ln.strip() == b"MOTION")
        lines = lines[: m + 3 + SOURCE_FRAMES]
        eol = lines[m][len(lines[m].rstrip(b"\r\n")) :]
        rows = [ln for ln in lines[m + 3 :] if ln.strip()]
        s = int(rng.integers(0, max(1, len(rows) - n)))
        data = b"".join(lines[: m + 1] + [b"Frames: %d" % len(rows[s : s + n]) + eol, lines[m + 2]] + rows[s : s + n])
    elif fmt == "trc":
        head = lines[:5]
        keys = head[1].rstrip(b"\r\n").split(b"\t")
        vals = head[2].rstrip(b"\r\n").split(b"\t")
        rows = [ln for ln in lines[5:] if ln.strip()]
        s = int(rng.integers(0, max(1, len(rows) - n)))
        rows = rows[s : s + n]
        vals[keys.index(b"NumFrames")] = b"%d" % len(rows)
        head[2] = b"\t".join(vals) + head[2][len(head[2].rstrip(b"\r\n")) :]
        data = b"".join(head + rows)
    return Base(fmt, name, data, asf, asf_name)


# --- mutations ------------------------------------------------------------------------------


def mutate(kind: str, base: Base, rng: np.random.Generator) -> tuple[bytes, bytes | None]:
    """``(mutated file, mutated ASF or None)`` for a mutation kind (see :data:`KINDS`)."""
    data, asf = base.data, base.asf
    if base.fmt == "amc" and asf is not None and kind not in BREAK and rng.random() < 0.1:
        return data, _mutate_bytes(kind, "asf", asf, rng)  # mutate the skeleton instead
    if kind in BREAK:
        return _break(kind, base, rng)
    return _mutate_bytes(kind, base.fmt, data, rng), asf


def _numbers(data: bytes) -> list[re.Match]:
    return list(_NUM.finditer(data))


def _mutate_bytes(kind: str, fmt: str, data: bytes, rng: np.random.Generator) -> bytes:
    n = len(data)
    lines = _lines(data)
    if kind == "truncate":
        return data[: int(rng.integers(1, n))]
    if kind == "truncate_line":
        return b"".join(lines[: int(rng.integers(1, len(lines) + 1))])
    if kind == "byte_flip":
        b = bytearray(data)
        for _ in range(int(rng.integers(1, 4))):
            b[int(rng.integers(0, n))] ^= int(rng.integers(1, 256))
        return bytes(b)
    if kind == "control_byte":
        c = bytes([CONTROL[int(rng.integers(0, len(CONTROL)))]])
        if rng.random() < 0.5:  # at the start of a line (0x7F before an AMC frame...)
            k = int(rng.integers(0, len(lines)))
            return b"".join(lines[:k] + [c + lines[k]] + lines[k + 1 :])
        k = int(rng.integers(0, n + 1))
        return data[:k] + c + data[k:]
    if kind in ("nonfinite", "number", "wrong_count"):
        return _mutate_number(kind, fmt, data, rng)
    if kind in ("eol", "bom_eol"):
        data = _mixed_eol(lines, rng)
        return b"\xef\xbb\xbf" + data if kind == "bom_eol" else data
    if kind == "bom":
        return b"\xef\xbb\xbf" + data
    if kind == "blanks":
        return _blanks(fmt, lines, rng)
    if kind in ("dup_line", "del_line", "swap_lines"):
        return _line_edit(kind, lines, rng)
    if kind == "huge_line":
        size = int(rng.choice([10_000, 100_000, 400_000]))
        fill = [b"1" * size, b"1 " * (size // 2), b"a" * size, b"\t" * size, b" " * size][int(rng.integers(0, 5))]
        k = int(rng.integers(0, len(lines) + 1))
        return b"".join(lines[:k] + [fill + b"\n"] + lines[k:])
    if kind == "header":
        return _header(fmt, lines, rng)
    raise ValueError(kind)


def _line_edit(kind: str, lines: list[bytes], rng: np.random.Generator) -> bytes:
    """One line duplicated, deleted, or swapped with the next."""
    if kind == "dup_line":
        k = int(rng.integers(0, len(lines)))
        return b"".join(lines[: k + 1] + lines[k:])
    if kind == "del_line":
        k = int(rng.integers(0, len(lines)))
        return b"".join(lines[:k] + lines[k + 1 :])
    k = int(rng.integers(0, max(1, len(lines) - 1)))
    return b"".join(lines[:k] + lines[k + 1 : k + 2] + lines[k : k + 1] + lines[k + 2 :])


def _mutate_number(kind: str, fmt: str, data: bytes, rng: np.random.Generator) -> bytes:
    """One number replaced: by a non-finite word, a scaled value, or removed / doubled."""
    nums = _numbers(data) if fmt != "c3d" else []
    if not nums:
        return data[:-1]
    m = nums[int(rng.integers(0, len(nums)))]
    if kind == "nonfinite":
        new = SPECIAL[int(rng.integers(0, len(SPECIAL)))]
    elif kind == "number":
        v = float(m.group()) * float(rng.choice([-1, 0, 0.5, 10, 1e3, 1e6])) + float(rng.normal())
        new = rng.choice([b"%d" % int(v), b"%.3f" % v, b"%.17g" % v, b"%e" % v, b"%.25f" % v]).tobytes()
    else:
        new = b"" if rng.random() < 0.5 else m.group() + b" " + m.group()
    return data[: m.start()] + new + data[m.end() :]


def _mixed_eol(lines: list[bytes], rng: np.random.Generator) -> bytes:
    """Every line end drawn from LF, CRLF and CR."""
    out, prev = [], b""
    for ln in lines:
        body = ln.rstrip(b"\r\n")
        choices = [b"\n", b"\r\n", b"\r"]
        if prev == b"\r" and not body:
            choices = [b"\r\n", b"\r"]  # CR then a bare LF would merge two line ends
        prev = choices[int(rng.integers(0, len(choices)))]
        out.append(body + prev)
    return b"".join(out)


def _blanks(fmt: str, lines: list[bytes], rng: np.random.Generator) -> bytes:
    """Runs of blanks where one separated words: content kept. TRC: only in the header
    key and value lines (data rows are tab-separated, an extra tab is a gap)."""
    runs = [b"  ", b"\t", b" \t ", b"\t\t", b"   \t"]
    out = []
    for k, ln in enumerate(lines):
        if fmt == "trc":
            ok = k in (1, 2)
            sep = b"\t"
        else:
            ok = rng.random() < 0.3 and not ln.lower().startswith(b"frame time")
            sep = b" "
        if ok:
            parts = ln.split(sep)
            ln = parts[0] + b"".join(runs[int(rng.integers(0, len(runs)))] + p for p in parts[1:])
        out.append(ln)
    return b"".join(out)


def _header(fmt: str, lines: list[bytes], rng: np.random.Generator) -> bytes:
    """Change a header value: BVH Frames / Frame Time, TRC NumFrames / NumMarkers /
    DataRate / Units, AMC angle unit."""
    new = [b"0", b"-1", b"1e-9", b"1e9", b"nan", b"inf", b"2", b"0.5", b"", b"abc", b"1e308", b"99999999999"]
    v = new[int(rng.integers(0, len(new)))]
    if fmt == "bvh":
        m = next((k for k, ln in enumerate(lines) if ln.strip() == b"MOTION"), None)
        if m is not None and m + 2 < len(lines):
            k = m + 1 + int(rng.integers(0, 2))
            key = lines[k].split(b":")[0]
            lines[k] = key + b": " + v + b"\n"
    elif fmt == "trc" and len(lines) > 2:
        vals = lines[2].rstrip(b"\r\n").split(b"\t")
        vals[int(rng.integers(0, len(vals)))] = v if rng.random() < 0.7 else b"cm"
        lines[2] = b"\t".join(vals) + b"\n"
    elif fmt == "amc":
        k = next((k for k, ln in enumerate(lines) if ln.strip().upper() in (b":DEGREES", b":RADIANS")), 0)
        lines[k] = [b":RADIANS\n", b":DEGREES\n", b":FULLY-SPECIFIED\n", b"\n"][int(rng.integers(0, 4))]
    return b"".join(lines)


def _break(kind: str, base: Base, rng: np.random.Generator) -> tuple[bytes, bytes | None]:
    """Mutations whose file must be refused: duplicated or undefined bones/joints."""
    lines = _lines(base.data)
    if base.fmt == "amc":
        if rng.random() < 0.3 and base.asf is not None:
            return base.data, _break_asf(kind, base.asf, rng)
        bone_lines = [k for k, ln in enumerate(lines) if ln[:1].isalpha()]
        k = bone_lines[int(rng.integers(0, len(bone_lines)))]
        if kind == "dup_bone":
            lines.insert(k + int(rng.integers(0, 2)), lines[k])
        else:
            lines[k] = b"ghost_bone" + lines[k][lines[k].index(b" ") :]
    elif base.fmt == "bvh":
        decl = [k for k, ln in enumerate(lines) if ln.split()[:1] in ([b"JOINT"], [b"ROOT"])]
        if kind == "dup_bone":
            a, b = (int(x) for x in rng.choice(len(decl), 2, replace=False))
            name, old = lines[decl[a]].split()[1], lines[decl[b]].split()[1]
            lines[decl[b]] = lines[decl[b]].replace(b" " + old, b" " + name, 1)
        else:  # a brace lost: the hierarchy no longer closes
            braces = [k for k, ln in enumerate(lines) if ln.strip() in (b"{", b"}")]
            del lines[braces[int(rng.integers(0, len(braces)))]]
    else:  # TRC: NumMarkers no longer matches the labels
        vals = lines[2].split(b"\t")
        keys = lines[1].split(b"\t")
        i = keys.index(b"NumMarkers")
        vals[i] = b"%d" % (int(vals[i]) + (1 if kind == "dup_bone" else -1))
        lines[2] = b"\t".join(vals)
    return b"".join(lines), base.asf


def _break_asf(kind: str, asf: bytes, rng: np.random.Generator) -> bytes:
    lines = _lines(asf)
    if kind == "dup_bone":  # a second bone block with a name already used
        begins = [k for k, ln in enumerate(lines) if ln.strip() == b"begin"][:-1]  # the last is :hierarchy's
        k = begins[int(rng.integers(1, len(begins)))] if len(begins) > 1 else begins[0]
        end = next(j for j in range(k, len(lines)) if lines[j].strip() == b"end")
        block = lines[k : end + 1]
        where = next(j for j, ln in enumerate(lines) if ln.strip() == b":hierarchy")
        return b"".join(lines[:where] + block + lines[where:])
    # a hierarchy line naming a bone that :bonedata does not define
    k = len(lines) - next(j for j, ln in enumerate(reversed(lines)) if ln.strip() == b"end")
    return b"".join(lines[: k - 1] + [b"  root ghost_bone\n"] + lines[k - 1 :])
