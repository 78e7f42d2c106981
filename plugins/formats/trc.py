"""TRC marker files (Motion Analysis / OpenSim, tab- or comma-separated): reader and writer.

Layout: ``PathFileType`` line; a line of keys (``DataRate CameraRate NumFrames NumMarkers
Units ...``) and a line of their values; ``Frame# Time <label> <tab> <tab> <label>...``;
``X1 Y1 Z1 X2...``; then one row per frame: frame number, time, 3 values per marker.
A gap is an empty field or ``NaN``. ``NumFrames`` and ``NumMarkers`` are checked against
the data; a ``NumFrames`` above the complete rows present is read as those rows, with a
warning (``strict``: refused); rows that end early or carry unnamed markers beyond
``NumMarkers`` (Motion Analysis) and fewer labels than ``NumMarkers`` are read with a
warning; lines ending CR CR LF count once. Units (``mm``, ``cm``, ``m``, ``in``) are converted to metres. Axes are kept
(OpenSim files are y-up); ``metadata["up_axis"]`` is guessed from the data
(:func:`~mocapflow.framework.markers.guess_up_axis`).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from pydantic import Field

from mocapflow.framework.components import Format
from mocapflow.framework.components import Params as BaseParams
from mocapflow.framework.errors import DataError, ParseError
from mocapflow.framework.markers import Markers, guess_up_axis, to_y_up

from ._common import (
    MAX_FPS,
    MAX_METRES,
    check_text,
    file_metadata,
    read_bytes,
    strict_float,
    strict_int,
    text_body,
    text_head,
)
from .c3d import UNITS_TO_METRES

__all__ = ["TrcFormat", "read_trc", "write_trc"]

_HEADER_LINES = 5
_WS = re.compile(r"[ \t]+")


def _lines(data: bytes, n: int) -> tuple[list[str], int]:
    """The first ``n`` lines (decoded, without line ends) and the byte offset after them."""
    out, pos = [], 0
    for _ in range(n):
        end = data.find(b"\n", pos)
        end = len(data) if end < 0 else end
        out.append(data[pos:end].decode("latin-1").rstrip("\r"))
        pos = min(end + 1, len(data))
    return out, pos


_SPACE = " \t\r\x0b\x0c"  # ASCII whitespace of a line (the tokenizer's)


def _header_fields(line: str) -> list[str]:
    """Fields of a header line: split on runs of tabs and spaces (OpenSim pads values with
    spaces and separates them with one or more tabs)."""
    return [f for f in _WS.split(line.strip(_SPACE)) if f]


def _key_values(keys_line: str, vals_line: str) -> dict[str, str]:
    keys, vals = _header_fields(keys_line), _header_fields(vals_line)
    if len(keys) != len(vals):  # empty values in a tab-separated line: pair by tab position
        keys = [k.strip(_SPACE) for k in keys_line.split("\t")]
        vals = [v.strip(_SPACE) for v in vals_line.split("\t")]
    return {k: v for k, v in zip(keys, vals, strict=False) if k}


def _field(text: bytes) -> float:
    """One data field: empty or NaN is a gap (NaN); otherwise a finite decimal number."""
    t = text.strip()
    if not t or t.lstrip(b"+-").lower() == b"nan":
        return np.nan
    return strict_float(t)


def _slow_row(path: Path, line: int, text: bytes, width: int, last: bool, odd: dict[str, list[int]]) -> list[float]:
    """Fields of a data row that is not ``width`` plain numbers (gaps, NaN, garbage):
    tab-separated (an empty field is a gap), or whitespace-separated without tabs.
    Motion Analysis writers end a row after its last visible marker and append unnamed
    markers beyond ``NumMarkers`` to some rows: a short row (not the file's last: that one
    is a cut file) reads its missing markers as gaps, a long one keeps its first ``width``
    fields; both are counted in ``odd`` for the warning."""
    fields = text.split(b"\t") if b"\t" in text else text.split()
    extra = sum(1 for f in fields[width:] if f.strip())
    if len(fields) < width:
        if last or len(fields) < 2:
            raise ParseError(path, line, f"expected {width} fields (frame, time, 3 x NumMarkers), found {len(fields)}")
        odd["short"].append(line)
        fields = fields + [b""] * (width - len(fields))
    elif extra:
        odd["long"].append(line)
    try:
        row = [_field(f) for f in fields[:width]]
    except ValueError as exc:
        raise ParseError(
            path, line, f"expected a finite number, an empty field or NaN, found {str(exc)[:40]!r}"
        ) from None
    return row


def _body(path: Path, data: bytes) -> tuple[bytes, list[str], int]:
    """The text parsed (:func:`text_body`; CR CR LF, a Windows double conversion, ends one
    line; a comma-separated file, as spreadsheets export it, has its commas read as tabs),
    its header lines and the offset after them."""
    body = text_body(data.replace(b"\r\r\n", b"\r\n") if b"\r\r\n" in data else data)
    check_text(path, body)
    head, pos = _lines(body, _HEADER_LINES)
    if "," in head[1] and "\t" not in head[1]:
        body = body.replace(b",", b"\t")
        head, pos = _lines(body, _HEADER_LINES)
    return body, head, pos


def _odd_rows(odd: dict[str, list[int]], n_markers: int) -> list[str]:
    out = []
    if odd["short"]:
        k = odd["short"]
        out.append(f"{len(k)} data rows end before their last marker (first at line {k[0]}): read as gaps")
    if odd["long"]:
        k = odd["long"]
        out.append(
            f"{len(k)} data rows hold values beyond the {n_markers} markers of NumMarkers (first at line "
            f"{k[0]}): unnamed markers, not read"
        )
    return out


def _sized_labels(
    path: Path, line: int, labels: tuple[str, ...], n_markers: int, n_rows: int, n_bytes: int, warn: list[str]
) -> tuple[str, ...]:
    """``labels`` named up to ``NumMarkers`` (``pointN``, with a warning), once the table the
    header implies fits the file: a field costs at least its separator, so ``NumMarkers``
    beyond what the bytes can hold is refused before anything is allocated."""
    width = 2 + 3 * n_markers
    if n_rows * width > 2 * n_bytes + 4096:
        raise ParseError(
            path, line, f"NumMarkers {n_markers}: {n_rows} rows of {width} fields cannot fit in {n_bytes:,} bytes"
        )
    if len(labels) < n_markers:
        warn.append(f"line 4: {len(labels)} labels for NumMarkers {n_markers}: the rest named by their index")
        labels += tuple(f"point{k + 1}" for k in range(len(labels), n_markers))
    return labels


def _frame_count(path: Path, n_frames: int, rows: np.ndarray, header_end: int, strict: bool, warn: list[str]) -> int:
    """The frames to read: ``NumFrames``, or the rows present when there are fewer (each
    complete and checked after; exporters that write the capture's count, not the rows
    kept), with a warning; ``strict`` or more rows than announced: a ParseError."""
    if len(rows) == n_frames:
        return n_frames
    if strict or not 0 < len(rows) < n_frames:
        where = int(rows[-1]) if len(rows) else header_end
        raise ParseError(path, where, f"expected {n_frames} data rows (NumFrames), found {len(rows)}")
    warn.append(f"line 3: NumFrames says {n_frames}, the file holds {len(rows)} data rows: read {len(rows)}")
    return len(rows)


def read_trc(path: str | Path, y_up: bool = False, strict: bool = False) -> Markers:
    """Read a TRC file (``y_up``: rotate z-up data to y-up; default the file's axes;
    ``strict``: refuse a ``NumFrames`` larger than the rows present instead of reading the
    rows with a warning in ``metadata["warnings"]``).

    Positions (T, M, 3) metres, NaN for gaps; metadata ``path``, ``format`` ("trc"),
    ``checksum``, ``units``, ``up_axis``, ``first_frame``, ``source_fps``, ``source_frames``.
    ParseError names the file, the 1-based line and what was expected, also for ``inf`` and
    values beyond 10 km (the value policy of ``_common``); ``NaN`` and empty fields are gaps.
    """
    path = Path(path)
    data = read_bytes(
        path, lambda head: text_head(path, head, (b"PathFileType",), "a TRC header starting with 'PathFileType'")
    )
    from ._text_kernels import tokenize  # after the header check: a foreign file costs no kernel load

    body, head, pos = _body(path, data)

    def at(line: int) -> int:  # a header line, or the last line of a file that ends before it
        return min(line, body.count(b"\n") + 1)

    if not head[0].startswith("PathFileType"):
        raise ParseError(path, 1, f"expected a TRC header starting with 'PathFileType', found {head[0][:40]!r}")
    info = _key_values(head[1], head[2])
    try:
        n_frames, n_markers = strict_int(info["NumFrames"]), strict_int(info["NumMarkers"])
        rate = strict_float(info.get("DataRate") or info["CameraRate"])
    except (KeyError, ValueError):
        raise ParseError(path, at(3), "expected NumFrames, NumMarkers and DataRate values") from None
    if n_frames < 1 or n_markers < 1:
        raise ParseError(path, at(3), f"expected NumFrames >= 1 and NumMarkers >= 1, found {n_frames} and {n_markers}")
    units = info.get("Units", "mm").lower()
    if units not in UNITS_TO_METRES:
        raise ParseError(path, at(3), f"expected Units among {sorted(UNITS_TO_METRES)}, found {units!r}")
    if not 0 < rate <= MAX_FPS:
        raise ParseError(path, at(3), f"expected a DataRate in (0, {MAX_FPS:g}] Hz, found {rate}")
    labels = tuple(lb.strip(_SPACE) for lb in head[3].split("\t")[2:] if lb.strip(_SPACE))
    if len(labels) != n_markers and "\t" not in head[3]:
        labels = tuple(_header_fields(head[3])[2:])
    warn: list[str] = []
    if len(labels) > n_markers or not labels:
        raise ParseError(path, at(4), f"expected {n_markers} marker labels (NumMarkers), found {len(labels)}")
    width = 2 + 3 * n_markers
    tok = tokenize(np.frombuffer(body, dtype=np.uint8), pos, _HEADER_LINES + 1)
    starts, lens, lines, _h, values, isnum = tok[:6]
    if tok[6] >= 0:  # check_text already rejects these; never read a cut-off token stream
        raise ParseError(path, int(tok[7]), "expected text, found a binary control byte")
    rows, first, counts = np.unique(lines, return_index=True, return_counts=True)
    labels = _sized_labels(path, at(3), labels, n_markers, len(rows), len(body), warn)
    n_frames = _frame_count(path, n_frames, rows, at(_HEADER_LINES), strict, warn)
    table = np.full((n_frames, width), np.nan)
    full = counts == width
    if full.all() and isnum.all():
        table[:] = values.reshape(n_frames, width)
        slow = np.zeros(0, np.int64)
    else:  # rows with gaps (empty fields), NaN or garbage: split those rows on tabs
        lo = first[full]
        idx = lo[:, None] + np.arange(width)
        table[full] = values[idx]
        slow = np.flatnonzero(~full | ~np.logical_and.reduceat(isnum, first))
    odd: dict[str, list[int]] = {"short": [], "long": []}
    for r in slow:
        s = body.rfind(b"\n", 0, starts[first[r]]) + 1  # the whole line: a leading tab is an empty field
        e = body.find(b"\n", s)
        text = body[s : len(body) if e < 0 else e].rstrip(b"\r")
        table[r] = _slow_row(path, int(rows[r]), text, width, r == len(rows) - 1, odd)
    warn += _odd_rows(odd, n_markers)
    bad_head = ~((np.abs(table[:, 0]) < 1e9) & (table[:, 0] == np.round(table[:, 0])) & (np.abs(table[:, 1]) < 1e9))
    if bad_head.any():
        bad = int(np.argmax(bad_head))
        raise ParseError(
            path,
            int(rows[bad]),
            f"expected an integer frame number and a time, found {table[bad, 0]:g} {table[bad, 1]:g}",
        )
    pos3 = table[:, 2:].reshape(n_frames, n_markers, 3) * UNITS_TO_METRES[units]
    far = np.abs(pos3) > MAX_METRES
    if far.any():
        f, m, _a = np.argwhere(far)[0]
        raise ParseError(
            path, int(rows[f]), f"expected marker {labels[m]!r} within {MAX_METRES:g} m, found {pos3[f, m].max():g} m"
        )
    pos3[~np.isfinite(pos3).all(-1)] = np.nan
    meta = file_metadata(path, data, "trc")
    meta.update(
        units=units,
        first_frame=int(table[0, 0]),
        up_axis=guess_up_axis(pos3),
        up_axis_source="guessed from data",
        source_fps=rate,
        source_frames=n_frames,
        warnings=warn,
    )
    out = Markers(labels=labels, positions=pos3, fps=rate, name=path.stem, metadata=meta)
    return to_y_up(out) if y_up else out


def write_trc(markers: Markers, path: str | Path, units: str = "mm", precision: int = 10) -> None:
    """Write markers as TRC (gaps as empty fields) in ``units`` (``mm``, ``cm``, ``m``, ``in``)
    with ``precision`` significant digits per value."""
    if units not in UNITS_TO_METRES:
        raise DataError(f"units must be one of {sorted(UNITS_TO_METRES)}, got {units!r}")
    t, m = markers.n_frames, markers.n_markers
    first = int(markers.metadata.get("first_frame", 1))
    head = [
        f"PathFileType\t4\t(X/Y/Z)\t{Path(path).name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
        f"{markers.fps:g}\t{markers.fps:g}\t{t}\t{m}\t{units}\t{markers.fps:g}\t{first}\t{t}",
        "Frame#\tTime\t" + "\t".join(f"{lb}\t\t" for lb in markers.labels),
        "\t\t" + "\t".join(f"X{k}\tY{k}\tZ{k}" for k in range(1, m + 1)),
        "",
    ]
    vals = markers.positions.reshape(t, 3 * m) / UNITS_TO_METRES[units]
    g = f"{{:.{precision}g}}"
    rows = []
    for i, row in enumerate(vals.tolist()):
        cells = ["" if v != v else g.format(v) for v in row]
        rows.append(f"{first + i}\t{g.format(i / markers.fps)}\t" + "\t".join(cells))
    Path(path).write_text("\n".join(head + rows) + "\n", encoding="latin-1")


class TrcFormat(Format):
    """TRC marker trajectories (tab-separated): reader and writer."""

    name: ClassVar[str] = "trc"
    extensions: ClassVar[tuple[str, ...]] = (".trc",)
    produces: ClassVar[str] = "markers"

    class Params(BaseParams):
        y_up: bool = Field(False, description="rotate z-up data to y-up (default: keep the file's axes)")
        strict: bool = Field(False, description="refuse a NumFrames above the rows present (default: read them, warn)")

    params: Params

    def read(self, path: str | Path) -> Any:
        return read_trc(path, y_up=self.params.y_up, strict=self.params.strict)

    def write(self, obj: Any, path: str | Path) -> None:
        write_trc(obj, path)
