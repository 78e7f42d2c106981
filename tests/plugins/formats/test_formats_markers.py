"""Marker formats: C3D (the NumPy parser, checked against the c3d package's per-frame reader)
and TRC (reader, writer, gaps, header checks); the Markers data model."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import corpus_path

from mocapflow.framework.errors import DataError, ParseError
from mocapflow.framework.markers import Markers, guess_up_axis, to_y_up
from mocapflow.plugins.formats.trc import read_trc, write_trc


def small_markers(t: int = 4, gaps: bool = True) -> Markers:
    rng = np.random.default_rng(0)
    pos = rng.uniform(0, 0.4, size=(t, 3, 3))
    pos[..., 1] = rng.uniform(0.1, 1.8, size=(t, 3))  # y up: a person's height, above the floor
    if gaps:
        pos[1, 2] = np.nan
    return Markers(("A", "B.two", "C"), pos, 100.0, name="small", metadata={"first_frame": 1})


def test_markers_model() -> None:
    m = small_markers()
    assert m.n_frames == 4 and m.n_markers == 3 and m.duration == pytest.approx(0.04)
    assert m.gaps.sum() == 1 and m.gaps[1, 2]
    assert m.select(["C", "A"]).labels == ("C", "A")
    assert m.slice(1, 3).metadata["source_start_frame"] == 1
    with pytest.raises(DataError):
        Markers(("A",), np.zeros((2, 2, 3)), 100.0)
    with pytest.raises(DataError):
        m.index("Z")


def test_to_y_up_is_a_rotation() -> None:
    m = small_markers(gaps=False)
    z = Markers(
        m.labels,
        np.stack([m.positions[..., 0], -m.positions[..., 2], m.positions[..., 1]], -1),
        m.fps,
        metadata={"up_axis": "+z"},
    )
    assert guess_up_axis(z.positions, "z") == "+z"
    back = to_y_up(z)
    np.testing.assert_allclose(back.positions, m.positions, atol=1e-15)
    assert back.metadata["up_axis"] == "+y"
    assert to_y_up(m) is m


def test_trc_round_trip_with_gaps(tmp_path: Path) -> None:
    m = small_markers()
    write_trc(m, tmp_path / "s.trc")
    back = read_trc(tmp_path / "s.trc")
    assert back.labels == m.labels and back.fps == 100.0 and back.metadata["up_axis"] == "+y"
    np.testing.assert_allclose(back.positions, m.positions, atol=1e-9, equal_nan=True)
    write_trc(m, tmp_path / "m.trc", units="m")
    np.testing.assert_allclose(read_trc(tmp_path / "m.trc").positions, m.positions, atol=1e-9, equal_nan=True)


def test_trc_layouts_of_other_writers(tmp_path: Path) -> None:
    """Comma-separated (spreadsheet exports, pyomeca's test file), CR CR LF line ends,
    Motion Analysis rows that end after their last visible marker, fewer labels than
    NumMarkers: read, each with what it repaired in the warnings."""
    m = small_markers()
    write_trc(m, tmp_path / "s.trc")
    text = (tmp_path / "s.trc").read_text()
    ref = read_trc(tmp_path / "s.trc")
    (tmp_path / "comma.trc").write_text(text.replace("\t", ",").replace("\n", ",,,\n"))
    comma = read_trc(tmp_path / "comma.trc")
    assert comma.labels == ref.labels
    np.testing.assert_array_equal(comma.positions, ref.positions)
    (tmp_path / "crcr.trc").write_bytes(text.replace("\n", "\r\r\n").encode())
    np.testing.assert_array_equal(read_trc(tmp_path / "crcr.trc").positions, ref.positions)
    lines = text.splitlines()
    lines[6] = "\t".join(lines[6].split("\t")[:5])  # frame 1 ends after its first marker
    (tmp_path / "short.trc").write_text("\n".join(lines) + "\n")
    short = read_trc(tmp_path / "short.trc")
    assert np.isnan(short.positions[0, 1:]).all() and np.array_equal(short.positions[0, 0], ref.positions[0, 0])
    assert "1 data rows end before their last marker (first at line 7)" in short.metadata["warnings"][0]
    lines = text.splitlines()
    lines[3] = lines[3].replace("C\t\t", "")
    (tmp_path / "lab.trc").write_text("\n".join(lines) + "\n")
    lab = read_trc(tmp_path / "lab.trc")
    assert lab.labels == ("A", "B.two", "point3") and "2 labels for NumMarkers 3" in lab.metadata["warnings"][0]
    lines[2] = lines[2].replace("\t4\t3\t", "\t4\t99999999999\t")  # no file of this size holds that
    (tmp_path / "huge.trc").write_text("\n".join(lines) + "\n")
    with pytest.raises(ParseError, match="NumMarkers 99999999999: 4 rows .* cannot fit") as e:
        read_trc(tmp_path / "huge.trc")
    assert e.value.line == 3


def test_trc_header_checks(tmp_path: Path) -> None:
    write_trc(small_markers(), tmp_path / "s.trc")
    lines = (tmp_path / "s.trc").read_text().splitlines()
    bad = list(lines)
    bad[2] = bad[2].replace("\t4\t3\t", "\t5\t3\t")  # NumFrames 5, 4 rows
    (tmp_path / "f.trc").write_text("\n".join(bad) + "\n")
    with pytest.raises(ParseError) as e:  # strict: refused; by default the 4 rows are read (a warning)
        read_trc(tmp_path / "f.trc", strict=True)
    assert e.value.line == len(lines) and "NumFrames" in e.value.message
    assert read_trc(tmp_path / "f.trc").n_frames == 4
    bad = list(lines)
    bad[2] = bad[2].replace("\t4\t3\t", "\t4\t2\t")
    (tmp_path / "m.trc").write_text("\n".join(bad) + "\n")
    with pytest.raises(ParseError, match="NumMarkers") as e:
        read_trc(tmp_path / "m.trc")
    assert e.value.line == 4
    bad = list(lines)
    bad[7] = bad[7] + "\t1.0\t2.0"  # an unnamed marker beyond NumMarkers: not read, counted
    (tmp_path / "w.trc").write_text("\n".join(bad) + "\n")
    w = read_trc(tmp_path / "w.trc")
    assert "beyond the 3 markers of NumMarkers (first at line 8)" in w.metadata["warnings"][0]
    bad[-1] = bad[-1].rsplit("\t", 3)[0]  # the last row cut short: a cut file
    (tmp_path / "c.trc").write_text("\n".join(bad) + "\n")
    with pytest.raises(ParseError, match="fields") as e:
        read_trc(tmp_path / "c.trc")
    assert e.value.line == len(bad)
    (tmp_path / "x.trc").write_text("hello\n")
    with pytest.raises(ParseError, match="PathFileType"):
        read_trc(tmp_path / "x.trc")


def test_trc_corpus() -> None:
    for name, frames, markers in [
        ("subject01_walk1.trc", 151, 41),
        ("subject02_running.trc", 600, 41),
        ("subject01_static.trc", 300, 49),
    ]:
        m = read_trc(corpus_path("trc", "opensim", name))
        assert m.positions.shape == (frames, markers, 3) and m.fps == 60.0
        assert m.metadata["up_axis"] == "+y" and m.labels[0] == "R.ASIS"
        # pelvis markers about 1 m above the floor (file in mm)
        assert 0.8 < np.nanmedian(m.positions[:, 0, 1]) < 1.2


# --- C3D ---------------------------------------------------------------------------------

C3D_FILES = [
    ("cmu", "85_02.c3d"),
    ("ezc3d_samples", "Vicon.c3d"),
    ("ezc3d_samples", "Qualisys.c3d"),
    ("numediart", "03_rolling.c3d"),
]


@pytest.mark.parametrize("folder, name", C3D_FILES)
def test_c3d_matches_package_reader(folder: str, name: str) -> None:
    c3d = pytest.importorskip("c3d")  # py-c3d: a peer reader, test-only
    from mocapflow.plugins.formats.c3d import read_c3d

    path = corpus_path("c3d", folder, name)
    m = read_c3d(path)
    with warnings.catch_warnings(), open(path, "rb") as handle:
        warnings.simplefilter("ignore")
        reader = c3d.Reader(handle)
        ref = np.array([p.copy() for _, p, _ in reader.read_frames(check_nan=False)], dtype=np.float64)
    want = ref[..., :3] / 1000.0  # every corpus file is in mm
    want[ref[..., 3] < 0] = np.nan
    np.testing.assert_allclose(m.positions, want, atol=1e-9, equal_nan=True)
    assert m.labels == tuple(str(lb).strip() for lb in reader.point_labels)
    assert m.fps == reader.point_rate and m.metadata["up_axis"] == "+z"
    y = read_c3d(path, y_up=True)
    assert np.nanmin(y.positions[..., 1]) > -0.1  # the floor is near y = 0 after conversion


def test_c3d_gaps_and_errors(tmp_path: Path) -> None:
    from mocapflow.plugins.formats.c3d import read_c3d

    m = read_c3d(corpus_path("c3d", "ezc3d_samples", "Vicon.c3d"))
    assert m.gaps.any() and np.isnan(m.positions[m.gaps]).all()
    data = corpus_path("c3d", "cmu", "85_02.c3d").read_bytes()
    whole = read_c3d(corpus_path("c3d", "cmu", "85_02.c3d"))
    (tmp_path / "t.c3d").write_bytes(data[: len(data) // 2])
    cut = read_c3d(tmp_path / "t.c3d")  # the whole frames present, with a warning
    assert 0 < cut.n_frames < 810 and "announces 810 frames" in cut.metadata["warnings"][0]
    np.testing.assert_array_equal(cut.positions, whole.positions[: cut.n_frames])
    with pytest.raises(ParseError, match="truncated C3D: the header announces 810 frames"):
        read_c3d(tmp_path / "t.c3d", strict=True)
    (tmp_path / "g.c3d").write_bytes(b"\x02\x00" + bytes(600))
    with pytest.raises(ParseError, match="0x50"):
        read_c3d(tmp_path / "g.c3d")
    (tmp_path / "e.c3d").write_bytes(b"")
    with pytest.raises(ParseError, match="empty"):
        read_c3d(tmp_path / "e.c3d")


def test_c3d_registered(registries) -> None:
    formats = registries["formats"]
    assert {"amc", "bvh", "c3d", "trc"} <= {name for name, _ in formats}
    assert formats.get("c3d").produces == "markers" and formats.get("trc").extensions == (".trc",)


def test_c3d_reads_without_the_package(monkeypatch: pytest.MonkeyPatch) -> None:
    import sys

    from mocapflow.plugins.formats.c3d import read_c3d

    monkeypatch.setitem(sys.modules, "c3d", None)  # makes `import c3d` raise ImportError
    m = read_c3d(corpus_path("c3d", "cmu", "85_02.c3d"))
    assert m.positions.shape == (810, 41, 3)


@pytest.mark.parametrize("up", ["+x", "-x", "-y", "+z", "-z"])
def test_to_y_up_maps_every_up_axis_to_plus_y_by_a_rotation(up):
    axis = {"x": 0, "y": 1, "z": 2}[up[1]]
    basis = np.eye(3)[None]  # one frame, three markers on the unit axes
    mk = Markers(name="m", labels=("a", "b", "c"), positions=basis.copy(), fps=100.0, metadata={"up_axis": up})
    out = to_y_up(mk).positions[0]
    # the up marker lands on +y, and the map is a proper rotation (no mirror)
    np.testing.assert_allclose(out[axis] * (1 if up[0] == "+" else -1), [0, 1, 0])
    assert np.isclose(np.linalg.det(out), 1.0)
