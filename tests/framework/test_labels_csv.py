"""Every bad row of a labels CSV is a ParseError naming file:line and what was expected (never
an internal error), and spans are checked against the clip they label."""

from __future__ import annotations

import pytest

from mocapflow.framework.errors import ParseError
from mocapflow.framework.labels import csv_labels

CLIPS = [{"clip_id": 1, "name": "walk1", "path": "/d/walk1.bvh", "fps": 30.0, "n_frames": 400}]


@pytest.mark.parametrize(
    ("body", "line", "expected"),
    [
        (b"walk1,walk,0,1,extra\n", 2, "expected 4 fields"),
        (b"walk1,walk,nan,1\n", 2, "column 'start': expected seconds (a finite number), got 'nan'"),
        (b"walk1,walk,0,inf\n", 2, "column 'end': expected seconds (a finite number), got 'inf'"),
        (b"walk1,walk,-1,2\n", 2, "expected seconds >= 0"),
        (b"walk1,walk,2,1\n", 2, "must come after start"),
        (b"walk1,walk,1000000,1000001\n", 2, "past the end of clip 'walk1' (400 frames"),
        (b"walk1,walk,1e300,\n", 2, "1e+300 s is beyond any clip"),
        (b"walk1,walk,,-0\n", 2, "shorter than a frame"),
        (b"walk1,walk,0,14\n", 2, "column 'end': 14 s is past the end"),
        (b"walk1,walk,0,1\nwalk1,caf\xe9,0,1\n", 3, "expected UTF-8 text, got byte 0xe9"),
        (b"walk1,walk,0,1\nwalk1,w\x00,0,1\n", 3, "expected printable text"),
        (b"walk1,walk,0.01,0.015\n", 2, "shorter than a frame"),
        (b'walk1,walk,0,1\n"walk1,walk\n', 3, "expected a CSV row"),
    ],
)
def test_bad_rows_name_file_line_and_what_was_expected(tmp_path, body, line, expected):
    f = tmp_path / "labels.csv"
    f.write_bytes(b"clip,label,start,end\n" + body)
    with pytest.raises(ParseError) as info:
        csv_labels(f, CLIPS)
    assert f"labels.csv:{line}:" in str(info.value) and expected in str(info.value), str(info.value)


def test_good_rows_still_read(tmp_path):
    f = tmp_path / "labels.csv"
    f.write_text('clip,label,start,end\n\nwalk1,"walk, slow",0.5,1.5\nwalk1,walk,,\nwalk1,tail,13,\nother,x,1,2\n')
    rows = csv_labels(f, CLIPS).to_pylist()
    assert [(r["label"], r["start_frame"], r["end_frame"]) for r in rows] == [
        ("walk, slow", 15, 45),
        ("walk", None, None),
        ("tail", 390, 400),
    ]
