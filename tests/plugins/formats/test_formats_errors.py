"""Bad input: every reader raises ParseError(path, line, what was expected).

Corrupted copies of corpus files are built in tmp_path; handmade files keep the core
suite meaningful without the corpus.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from conftest import corpus_path
from test_formats_amc import TINY_ASF, tiny_amc
from test_formats_bvh import REST, TINY_BVH, tiny_bvh

from mocapflow.framework.errors import MocapflowError, ParseError
from mocapflow.plugins.formats.asf_amc import read_amc, read_asf
from mocapflow.plugins.formats.bvh import read_bvh

FRAMES = [(0, 0, 0, 0, 0, 0, 1, 2, 3), (0, 0, 0, 0, 0, 0, 4, 5, 6), (0, 0, 0, 0, 0, 0, 7, 8, 9)]


def raises_at(fn, path: Path, line: int | None, match: str) -> ParseError:
    with pytest.raises(ParseError) as info:
        fn(path)
    err = info.value
    assert err.path == str(path) and err.line == line, (err.path, err.line, err.message)
    assert re.search(match, err.message), err.message
    assert str(path) in str(err)
    return err


@pytest.fixture
def tiny(tmp_path: Path) -> Path:
    (tmp_path / "tiny.asf").write_text(TINY_ASF)
    return tmp_path


def write(path: Path, text: str | bytes) -> Path:
    path.write_bytes(text.encode() if isinstance(text, str) else text)
    return path


# --- AMC / ASF -----------------------------------------------------------------------------


def test_amc_truncated_mid_frame(tiny: Path) -> None:
    lines = tiny_amc(FRAMES).splitlines()
    f = write(tiny / "t.amc", "\n".join(lines[:-2]) + "\n")  # frame 3 lacks a and b
    raises_at(read_amc, f, len(lines) - 2, r"frame 3 is incomplete .*file ends.*a")


def test_amc_truncated_mid_line(tiny: Path) -> None:
    text = tiny_amc(FRAMES)
    f = write(tiny / "t.amc", text[: text.rindex(" ")])  # last line "b 8" lost its last value
    raises_at(read_amc, f, len(text.splitlines()), r"expected 2 values for bone 'b', found 1")


def test_amc_nan_value(tiny: Path) -> None:
    lines = tiny_amc(FRAMES).splitlines()
    lines[4] = "a nan"
    f = write(tiny / "n.amc", "\n".join(lines))
    raises_at(read_amc, f, 5, r"finite number for bone 'a'.*nan")


def test_amc_bone_missing_from_asf(tiny: Path) -> None:
    lines = tiny_amc(FRAMES).splitlines()
    lines.insert(9, "tail 1 2")  # inside frame 2
    f = write(tiny / "m.amc", "\n".join(lines))
    raises_at(read_amc, f, 10, r"bone 'tail' is not")


def test_amc_bone_missing_from_asf_first_frame(tiny: Path) -> None:
    lines = tiny_amc(FRAMES).splitlines()
    lines.insert(4, "tail 1 2")
    f = write(tiny / "m.amc", "\n".join(lines))
    raises_at(read_amc, f, 5, r"bone 'tail' is not defined .* ASF")


def test_amc_frame_numbers_must_be_consecutive(tiny: Path) -> None:
    f = write(tiny / "c.amc", tiny_amc(FRAMES).replace("\n3\n", "\n5\n"))
    raises_at(read_amc, f, 11, r"expected frame number 3, found '5'")


def test_amc_empty_garbage_and_paths(tiny: Path) -> None:
    raises_at(read_amc, write(tiny / "e.amc", ""), 1, "empty")
    raises_at(read_amc, write(tiny / "w.amc", " \r\n\n"), 1, "empty")
    garbage = bytes(range(256)) * 4
    raises_at(read_amc, write(tiny / "g.amc", garbage), 1, "binary")
    raises_at(read_amc, tiny / "missing.amc", None, "not found")
    (tiny / "dir.amc").mkdir()
    raises_at(read_amc, tiny / "dir.amc", None, "directory")
    raises_at(read_asf, tiny / "nope.asf", None, "not found")


def test_amc_header_only(tiny: Path) -> None:
    raises_at(read_amc, write(tiny / "h.amc", ":FULLY-SPECIFIED\n:DEGREES\n"), 2, "expected frame blocks")


def test_amc_without_asf(tmp_path: Path) -> None:
    f = write(tmp_path / "x.amc", tiny_amc(FRAMES))
    raises_at(read_amc, f, None, "cannot find the ASF")


def test_asf_errors(tmp_path: Path) -> None:
    bad = TINY_ASF.replace("direction 0 1 0", "direction 0 one 0")
    raises_at(
        read_asf,
        write(tmp_path / "a.asf", bad),
        bad.splitlines().index("     direction 0 one 0") + 1,
        "3 numbers for direction",
    )
    bad = TINY_ASF.replace("    a b\n", "    a b tail\n")
    raises_at(read_asf, write(tmp_path / "b.asf", bad), bad.splitlines().index("    a b tail") + 1, "'tail'")
    bad = TINY_ASF.replace("dof rx\n", "dof rx tx\n")
    raises_at(read_asf, write(tmp_path / "c.asf", bad), bad.splitlines().index("    dof rx tx") + 1, "dofs")
    raises_at(read_asf, write(tmp_path / "d.asf", b"\x00\x01\x02ASF"), 1, "binary")


def test_parse_error_is_a_mocapflow_error() -> None:
    assert issubclass(ParseError, MocapflowError)


# --- BVH ---------------------------------------------------------------------------------------


def test_bvh_wrong_value_count(tmp_path: Path) -> None:
    short = REST[:-1]
    text = tiny_bvh([REST, short, REST])
    line = text.splitlines().index(" ".join(map(str, short))) + 1
    raises_at(read_bvh, write(tmp_path / "w.bvh", text), line, r"expected 18 values .*found 17")


def test_bvh_frame_count_mismatch_and_nan(tmp_path: Path) -> None:
    text = tiny_bvh([REST, REST])
    raises_at(read_bvh, write(tmp_path / "f.bvh", text), len(text.splitlines()), r"expected 3 frame lines .*found 2")
    bad = list(map(str, REST))
    bad[4] = "NaN"
    text = tiny_bvh([REST, bad, REST])
    raises_at(read_bvh, write(tmp_path / "n.bvh", text), text.splitlines().index(" ".join(bad)) + 1, "finite numbers")


def test_bvh_hierarchy_errors(tmp_path: Path) -> None:
    text = tiny_bvh([REST] * 3).replace(
        "CHANNELS 3 Xrotation Yrotation Zrotation", "CHANNELS 3 Xrotation Yrotation Wrotation"
    )
    raises_at(read_bvh, write(tmp_path / "c.bvh", text), 9, "channels")
    text = tiny_bvh([REST] * 3).replace("    OFFSET 10 0 0\n", "")
    closing = max(i for i, ln in enumerate(text.splitlines()) if ln == "  }") + 1  # LeftUpLeg's "}"
    raises_at(read_bvh, write(tmp_path / "o.bvh", text), closing, "'LeftUpLeg' has no OFFSET")
    head = TINY_BVH.split("MOTION")[0]
    raises_at(read_bvh, write(tmp_path / "m.bvh", head), head.count("\n") + 1, "MOTION")
    raises_at(read_bvh, write(tmp_path / "e.bvh", ""), 1, "empty")
    raises_at(read_bvh, write(tmp_path / "g.bvh", bytes(range(200))), 1, "binary")
    raises_at(read_bvh, write(tmp_path / "x.bvh", "hello\nMOTION\n"), 1, "HIERARCHY")


# --- corrupted copies of corpus files ----------------------------------------------------------


def test_corpus_truncated_amc(tmp_path: Path) -> None:
    src = corpus_path("cmu", "amc", "01")
    (tmp_path / "01.asf").write_bytes((src / "01.asf").read_bytes())
    data = (src / "01_01.amc").read_bytes()
    cut = data[: len(data) // 2]
    cut = cut[: cut.rindex(b"\n") + 1]
    f = write(tmp_path / "01_01.amc", cut)
    err = raises_at(read_amc, f, cut.count(b"\n"), "incomplete")
    assert "file ends" in err.message


def test_corpus_hdm05_corrupted_value(tmp_path: Path) -> None:
    src = sorted(corpus_path("hdm05", "amc", "dg").glob("*.amc"))[0]
    (tmp_path / "HDM_dg.asf").write_bytes((src.parent / "HDM_dg.asf").read_bytes())
    lines = src.read_bytes().split(b"\n")
    k = 500
    name = lines[k].split()[0]
    lines[k] = name + b" 1.0 x2\r"
    f = write(tmp_path / src.name, b"\n".join(lines))
    raises_at(read_amc, f, k + 1, "values for bone|finite number")


def test_corpus_bvh_missing_value(tmp_path: Path) -> None:
    src = corpus_path("bvh", "cmu_cgspeed", "01_01.bvh")
    lines = src.read_bytes().split(b"\n")
    k = len(lines) - 100
    lines[k] = lines[k].rsplit(b" ", 1)[0] if not lines[k].endswith(b" ") else lines[k].rstrip().rsplit(b" ", 1)[0]
    f = write(tmp_path / "01_01.bvh", b"\n".join(lines))
    raises_at(read_bvh, f, k + 1, r"expected 96 values on this frame line, found 95")
