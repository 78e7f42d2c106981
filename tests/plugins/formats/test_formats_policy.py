"""The readers never crash or lie. Each known case, one test:
short AMC bone lines, 0x7F before an AMC frame, non-finite and absurd values (the value
policy of ``plugins/formats/_common.py``), duplicated ASF/BVH names, BOM and CR-only
line ends, OpenSim TRC headers with runs of tabs."""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

import numpy as np
import pytest
from conftest import EXAMPLES_DATA, corpus_path
from test_formats_amc import TINY_ASF, tiny_amc
from test_formats_bvh import REST, tiny_bvh
from test_formats_errors import (
    FRAMES,
    raises_at,
    tiny,  # noqa: F401 - a pytest fixture, used by argument name
    write,
)
from test_formats_markers import small_markers

from mocapflow.plugins.formats import _common
from mocapflow.plugins.formats.asf_amc import read_amc, read_asf
from mocapflow.plugins.formats.bvh import read_bvh
from mocapflow.plugins.formats.trc import read_trc, write_trc

# --- AMC: short bone lines, 0x7F, duplicated bones --------------------------------------------


def test_amc_only_frame_with_a_short_root_line(tiny: Path) -> None:
    # the file: IndexError before the fix
    f = write(tiny / "s.amc", ":FULLY-SPECIFIED\n:DEGREES\n1\nroot 1 2\n")
    raises_at(read_amc, f, 4, r"expected 6 values for bone 'root', found 2")


def test_amc_short_last_line_of_the_only_frame(tiny: Path) -> None:
    # before the fix the kernel read past the table and accepted garbage
    f = write(tiny / "s.amc", ":FULLY-SPECIFIED\n:DEGREES\n1\nroot 1 2 3 4 5 6\na 1\nb 1\n")
    raises_at(read_amc, f, 6, r"expected 2 values for bone 'b', found 1")


def test_amc_extra_value_in_the_only_frame(tiny: Path) -> None:
    f = write(tiny / "s.amc", ":FULLY-SPECIFIED\n:DEGREES\n1\nroot 1 2 3 4 5 6 7\na 1\nb 1 2\n")
    raises_at(read_amc, f, 4, r"expected 6 values for bone 'root', found 7")


def test_amc_value_moved_to_the_next_line(tiny: Path) -> None:
    text = tiny_amc(FRAMES).replace("b 5 6\n", "b 5\n6\n")
    raises_at(read_amc, write(tiny / "m.amc", text), 10, r"expected 2 values for bone 'b', found 1")


def test_amc_bone_twice_in_the_first_frame(tiny: Path) -> None:
    lines = tiny_amc(FRAMES).splitlines()
    lines.insert(5, lines[4])  # "a 1" twice
    raises_at(read_amc, write(tiny / "d.amc", "\n".join(lines)), 6, r"bone 'a' appears twice")


def test_amc_fully_specified_single_frame_missing_a_bone(tiny: Path) -> None:
    # a one-frame file cut at a bone line used to be read as a complete frame
    f = write(tiny / "i.amc", ":FULLY-SPECIFIED\n:DEGREES\n1\nroot 1 2 3 4 5 6\na 1\n")
    raises_at(read_amc, f, 5, r"frame 1 is incomplete .*FULLY-SPECIFIED.*b")


def test_amc_control_byte_before_a_frame_is_an_error(tmp_path: Path) -> None:
    # before the fix the clip silently ended at frame 99
    src = EXAMPLES_DATA / "cmu" / "02" / "02_01.amc"
    data = src.read_bytes()
    k = data.index(b"\n100\n") + 1
    shutil.copy(src.parent / "02.asf", tmp_path)
    f = write(tmp_path / "02_01.amc", data[:k] + b"\x7f" + data[k:])
    raises_at(read_amc, f, data[:k].count(b"\n") + 1, r"binary byte 0x7f")
    assert read_amc(src).n_frames > 100


def test_amc_short_line_is_a_reject_and_ingest_goes_on(tmp_path: Path) -> None:
    import pyarrow.parquet as pq
    import yaml

    from mocapflow.framework import get_plugin_manager
    from mocapflow.framework.runner import run_pipeline

    data = tmp_path / "data"
    data.mkdir()
    src = EXAMPLES_DATA / "cmu" / "02"
    shutil.copy(src / "02.asf", data)
    shutil.copy(src / "02_01.amc", data / "good.amc")
    write(data / "short.amc", ":FULLY-SPECIFIED\n:DEGREES\n1\nroot 1 2\n")
    p = tmp_path / "ingest.yaml"
    p.write_text(
        yaml.safe_dump(
            {
                "name": "ingest",
                "workspace": str(tmp_path / "ws"),
                "steps": {"motions": {"uses": "formats.load", "with": {"paths": [str(data / "*.amc")]}}},
            }
        )
    )
    reports = run_pipeline(p, pm=get_plugin_manager(entry_points=False))
    assert reports[0].summary["clips"] == 1 and reports[0].summary["rejects"] == 1
    (rej,) = pq.read_table(tmp_path / "ws" / "motions" / "rejects.parquet").to_pylist()
    assert Path(rej["path"]).name == "short.amc" and rej["line"] == 4 and "expected 6 values" in rej["message"]


# --- the value policy --------------------------------------------------------------------------


def test_policy_bounds_are_documented() -> None:
    doc = _common.__doc__
    assert _common.MAX_METRES == 1e4 and "10 km" in doc and "float32" in doc
    assert _common.MAX_DEGREES == 1e6 and "10^6 degrees" in doc and "non-finite" in doc


def test_amc_absurd_values(tiny: Path) -> None:
    lines = tiny_amc(FRAMES).splitlines()
    for k, bad, what in [
        (4, "a 1e308", "angle within"),
        (4, "a 2e6", "angle within"),
        (3, "root 1e6 0 0 0 0 0", "root translation within"),
    ]:
        text = lines.copy()
        text[k] = bad
        raises_at(read_amc, write(tiny / "v.amc", "\n".join(text) + "\n"), k + 1, what)
    ok = lines.copy()
    ok[4] = "a 720"  # two turns: fine
    assert read_amc(write(tiny / "ok.amc", "\n".join(ok) + "\n")).n_frames == 3


def test_amc_overflowing_number_is_not_a_number(tiny: Path) -> None:
    lines = tiny_amc(FRAMES).splitlines()
    lines[4] = "a 1e309"
    raises_at(read_amc, write(tiny / "o.amc", "\n".join(lines)), 5, r"finite number for bone 'a'")


def test_bvh_absurd_values(tmp_path: Path) -> None:
    big = list(REST)
    big[0] = "1e308"  # root Xposition
    text = tiny_bvh([REST, big, REST])
    raises_at(
        read_bvh,
        write(tmp_path / "p.bvh", text),
        text.splitlines().index(" ".join(map(str, big))) + 1,
        r"Hips Xposition within 10000 m",
    )
    rot = list(REST)
    rot[3] = "-3e6"
    text = tiny_bvh([REST, rot, REST])
    raises_at(
        read_bvh,
        write(tmp_path / "r.bvh", text),
        text.splitlines().index(" ".join(map(str, rot))) + 1,
        r"Zrotation within 1e\+06 degrees",
    )
    text = tiny_bvh([REST] * 3).replace("OFFSET 0 10 0", "OFFSET 0 1e300 0")
    raises_at(read_bvh, write(tmp_path / "o.bvh", text), 8, r"OFFSET values within")
    text = tiny_bvh([REST] * 3).replace("Frame Time: 0.04", "Frame Time: 1e-300")
    raises_at(
        read_bvh,
        write(tmp_path / "t.bvh", text),
        text.splitlines().index("Frame Time: 1e-300") + 1,
        r"Frame Time between",
    )


def _trc(tmp_path: Path, edit=None, name: str = "m.trc") -> Path:
    f = tmp_path / name
    write_trc(small_markers(), f)
    if edit:
        lines = f.read_text().split("\n")
        edit(lines)
        f.write_text("\n".join(lines))
    return f


def test_trc_inf_is_an_error_not_a_gap(tmp_path: Path) -> None:
    def put_inf(lines: list[str]) -> None:
        cells = lines[7].split("\t")
        cells[3] = "inf"
        lines[7] = "\t".join(cells)

    raises_at(read_trc, _trc(tmp_path, put_inf), 8, r"finite number.*'inf'")

    # NaN and empty fields stay gaps
    def put_nan(lines: list[str]) -> None:
        cells = lines[7].split("\t")
        cells[3] = "NaN"
        lines[7] = "\t".join(cells)

    assert np.isnan(read_trc(_trc(tmp_path, put_nan, "n.trc")).positions[1, 0]).all()


def test_trc_absurd_values(tmp_path: Path) -> None:
    def put(lines: list[str]) -> None:
        cells = lines[6].split("\t")
        cells[4] = "1e308"
        lines[6] = "\t".join(cells)

    raises_at(read_trc, _trc(tmp_path, put), 7, r"marker 'A' within 10000 m")


def test_trc_short_row_is_an_error(tmp_path: Path) -> None:
    # a row cut short (a truncated file) used to be padded with gaps
    def cut(lines: list[str]) -> None:
        lines[-2] = lines[-2].rsplit("\t", 2)[0]

    f = _trc(tmp_path, cut)
    raises_at(read_trc, f, len(f.read_text().split("\n")) - 1, r"expected 11 fields .*found 9")


def test_c3d_non_finite_valid_sample_is_an_error(tmp_path: Path) -> None:
    from mocapflow.plugins.formats._c3d_parse import parse_c3d
    from mocapflow.plugins.formats.c3d import read_c3d

    src = corpus_path("c3d", "cmu", "85_02.c3d")
    m = read_c3d(src)
    data = bytearray(src.read_bytes())
    c = parse_c3d(bytes(data))
    assert c.float_data, "this test needs a float C3D"
    f, k = np.argwhere(~np.isnan(m.positions[..., 0]))[0]
    at = c.data_start + f * c.frame_bytes + k * 16
    data[at : at + 4] = struct.pack("<f", np.inf)
    bad = write(tmp_path / "inf.c3d", bytes(data))
    raises_at(read_c3d, bad, None, r"expected a finite position")
    # NaN coordinates with a valid residual: how Vicon Nexus and kinetics toolkit mark a
    # missing sample; a gap, counted in a warning
    data[at : at + 4] = struct.pack("<f", np.nan)
    nan = read_c3d(write(tmp_path / "nan.c3d", bytes(data)))
    assert np.isnan(nan.positions[f, k]).all() and "1 samples with NaN coordinates" in nan.metadata["warnings"][0]


# --- duplicated names --------------------------------------------------------------------------


def test_asf_duplicated_bone_name_names_its_line(tmp_path: Path) -> None:
    text = TINY_ASF.replace("     name c\n", "     name a\n")
    line = text.splitlines().index("     name a", text.splitlines().index("     name a") + 1) + 1
    err = raises_at(read_asf, write(tmp_path / "d.asf", text), line, r"bone name 'a' is already used by line \d+")
    assert f"line {text.splitlines().index('     name a') + 1}" in err.message


def test_asf_bone_with_two_parents(tmp_path: Path) -> None:
    text = TINY_ASF.replace("    a b\n", "    a b\n    c b\n")
    raises_at(
        read_asf, write(tmp_path / "p.asf", text), text.splitlines().index("    c b") + 1, r"'b' already has a parent"
    )


def test_bvh_duplicated_joint_name(tmp_path: Path) -> None:
    text = tiny_bvh([REST] * 3).replace("JOINT LeftUpLeg", "JOINT Spine")
    raises_at(
        read_bvh,
        write(tmp_path / "d.bvh", text),
        text.splitlines().index("  JOINT Spine", 6) + 1,
        r"joint name 'Spine' is already used at line 6",
    )


def test_bvh_second_offset_in_a_joint(tmp_path: Path) -> None:
    text = tiny_bvh([REST] * 3).replace("    OFFSET 0 10 0\n", "    OFFSET 0 10 0\n    OFFSET 0 11 0\n")
    raises_at(read_bvh, write(tmp_path / "o.bvh", text), 9, r"one OFFSET per joint")


# --- BOM and line ends -------------------------------------------------------------------------


def _same_motion(a, b) -> None:
    np.testing.assert_array_equal(a.rotations, b.rotations)
    np.testing.assert_array_equal(a.root_translation, b.root_translation)


@pytest.mark.parametrize("eol", ["\r", "\r\n", "\n"])
def test_amc_and_asf_with_bom_and_any_line_end(tiny: Path, eol: str) -> None:
    want = read_amc(write(tiny / "lf.amc", tiny_amc(FRAMES)))
    sub = tiny / "bom"
    sub.mkdir()
    write(sub / "tiny.asf", b"\xef\xbb\xbf" + TINY_ASF.replace("\n", eol).encode())
    got = read_amc(write(sub / "x.amc", b"\xef\xbb\xbf" + tiny_amc(FRAMES).replace("\n", eol).encode()))
    _same_motion(got, want)
    assert got.skeleton.names == want.skeleton.names
    np.testing.assert_array_equal(got.skeleton.offsets, want.skeleton.offsets)


def test_amc_cr_only_errors_count_lines(tiny: Path) -> None:
    text = tiny_amc(FRAMES).replace("b 5 6", "b 5").replace("\n", "\r")
    raises_at(read_amc, write(tiny / "cr.amc", text), 10, r"expected 2 values for bone 'b', found 1")


@pytest.mark.parametrize("eol", ["\r", "\r\n"])
def test_bvh_with_bom_and_any_line_end(tmp_path: Path, eol: str) -> None:
    text = tiny_bvh([REST] * 3)
    want = read_bvh(write(tmp_path / "lf.bvh", text))
    got = read_bvh(write(tmp_path / "x.bvh", b"\xef\xbb\xbf" + text.replace("\n", eol).encode()))
    _same_motion(got, want)


@pytest.mark.parametrize("eol", ["\r", "\r\n"])
def test_trc_with_bom_and_any_line_end(tmp_path: Path, eol: str) -> None:
    f = _trc(tmp_path)
    want = read_trc(f)
    got = read_trc(write(tmp_path / "x.trc", b"\xef\xbb\xbf" + f.read_bytes().replace(b"\n", eol.encode())))
    np.testing.assert_array_equal(got.positions, want.positions)
    assert got.labels == want.labels


def test_corpus_amc_cr_only_and_bom(tmp_path: Path) -> None:
    src = corpus_path("hdm05", "amc", "dg")
    amc = sorted(src.glob("*.amc"))[0]
    want = read_amc(amc)
    (tmp_path / "HDM_dg.asf").write_bytes(b"\xef\xbb\xbf" + (src / "HDM_dg.asf").read_bytes().replace(b"\r\n", b"\r"))
    data = amc.read_bytes().replace(b"\r\n", b"\n").replace(b"\n", b"\r")
    _same_motion(read_amc(write(tmp_path / amc.name, b"\xef\xbb\xbf" + data)), want)


# --- OpenSim TRC headers -----------------------------------------------------------------------


def test_trc_header_with_runs_of_tabs_and_spaces(tmp_path: Path) -> None:
    f = _trc(tmp_path)
    want = read_trc(f)

    def runs(lines: list[str]) -> None:  # keys one tab apart, values three (OpenSim's own files)
        lines[2] = "\t\t \t".join("  " + v for v in lines[2].split("\t"))

    got = read_trc(_trc(tmp_path, runs, "runs.trc"))
    np.testing.assert_array_equal(got.positions, want.positions)
    assert got.fps == want.fps and got.labels == want.labels


def test_corpus_opensim_trc_with_runs_of_tabs(tmp_path: Path) -> None:
    src = corpus_path("trc", "opensim", "subject01_walk1.trc")
    want = read_trc(src)
    lines = src.read_bytes().split(b"\n")
    lines[1] = lines[1].replace(b"\t", b"\t\t")
    lines[2] = lines[2].replace(b"\t", b"\t\t\t")
    got = read_trc(write(tmp_path / src.name, b"\n".join(lines)))
    np.testing.assert_array_equal(got.positions, want.positions)
    assert got.labels == want.labels and got.n_frames == 151


# --- every error names a line of the file (found by the fuzzer) --------------------------------


def test_bvh_cut_after_the_motion_header_names_a_line(tmp_path: Path) -> None:
    head = tiny_bvh([REST] * 3).split("Frame Time")[0]
    raises_at(
        read_bvh,
        write(tmp_path / "a.bvh", head.rstrip("\n")),
        head.count("\n"),
        r"'Frame Time: <value>', the file ends",
    )
    text = tiny_bvh([]).rstrip("\n")
    raises_at(
        read_bvh, write(tmp_path / "b.bvh", text), text.count("\n") + 1, r"frame lines .* after this line, found none"
    )


def test_asf_undefined_bone_with_a_non_ascii_blank_names_its_line(tmp_path: Path) -> None:
    text = TINY_ASF.replace("    a b\n", "    a \xa0b\n")
    raises_at(
        read_asf,
        write(tmp_path / "n.asf", text.encode("latin-1")),
        text.splitlines().index("    a \xa0b") + 1,
        r"hierarchy names bone '\\xa0b'",
    )
