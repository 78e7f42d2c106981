"""TRC marker files (Motion Analysis / OpenSim, tab-separated): reader and writer.

Layout: ``PathFileType`` line; a line of keys (``DataRate CameraRate NumFrames NumMarkers
Units ...``) and a line of their values; ``Frame# Time <label> <tab> <tab> <label>...``;
``X1 Y1 Z1 X2...``; then one row per frame: frame number, time, 3 values per marker.
A gap is an empty field or ``NaN``. ``NumFrames`` and ``NumMarkers`` are checked against
the data. Units (``mm``, ``cm``, ``m``, ``in``) are converted to metres. Axes are kept
(OpenSim files are y-up); ``metadata["up_axis"]`` is guessed from the data
(:func:`~mocapflow.framework.markers.guess_up_axis`).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from pydantic import Field

from mocapflow.framework.components import Format, Params
from mocapflow.framework.errors import DataError, ParseError
from mocapflow.framework.markers import Markers, guess_up_axis, to_y_up

from ._common import check_text, file_metadata, read_bytes
from .c3d import UNITS_TO_METRES

__all__ = ["TrcFormat", "read_trc", "write_trc"]

_HEADER_LINES = 5


def _lines(data: bytes, n: int) -> tuple[list[str], int]:
    """The first ``n`` lines (decoded, without line ends) and the byte offset after them."""
    out, pos = [], 0
    for _ in range(n):
        end = data.find(b"\n", pos)
        end = len(data) if end < 0 else end
        out.append(data[pos:end].decode("latin-1").rstrip("\r"))
        pos = min(end + 1, len(data))
    return out, pos


def read_trc(path: str | Path, y_up: bool = False) -> Markers:
    """Read a TRC file.

    Parameters
    ----------
    path : str or Path
    y_up : bool
        Rotate z-up data to y-up (default: keep the file's axes).

    Returns
    -------
    Markers
        positions (T, M, 3) metres, NaN for gaps; metadata ``path``, ``format`` ("trc"),
        ``checksum``, ``units``, ``up_axis``, ``first_frame``, ``source_fps``, ``source_frames``.

    Raises
    ------
    ParseError
        Naming the file, the 1-based line and what was expected.
    """
    from ._text import tokenize

    path = Path(path)
    data = read_bytes(path)
    check_text(path, data)
    head, pos = _lines(data, _HEADER_LINES)
    if not head[0].startswith("PathFileType"):
        raise ParseError(path, 1, f"expected a TRC header starting with 'PathFileType', found {head[0][:40]!r}")
    keys = [k.strip() for k in head[1].split("\t")]
    vals = [v.strip() for v in head[2].split("\t")]
    info = {k: v for k, v in zip(keys, vals) if k}
    try:
        n_frames, n_markers = int(info["NumFrames"]), int(info["NumMarkers"])
        rate = float(info.get("DataRate") or info["CameraRate"])
    except (KeyError, ValueError):
        raise ParseError(path, 3, "expected NumFrames, NumMarkers and DataRate values") from None
    units = info.get("Units", "mm").lower()
    if units not in UNITS_TO_METRES:
        raise ParseError(path, 3, f"expected Units among {sorted(UNITS_TO_METRES)}, found {units!r}")
    if not rate > 0:
        raise ParseError(path, 3, f"expected a positive DataRate, found {rate}")
    labels = tuple(lb.strip() for lb in head[3].split("\t")[2:] if lb.strip())
    if len(labels) != n_markers:
        raise ParseError(path, 4, f"expected {n_markers} marker labels (NumMarkers), found {len(labels)}")
    width = 2 + 3 * n_markers
    tok = tokenize(np.frombuffer(data, dtype=np.uint8), pos, _HEADER_LINES + 1)
    starts, lens, lines, _h, values, isnum = tok[:6]
    rows, first, counts = np.unique(lines, return_index=True, return_counts=True)
    if len(rows) != n_frames:
        where = int(rows[-1]) if len(rows) else _HEADER_LINES
        raise ParseError(path, where, f"expected {n_frames} data rows (NumFrames), found {len(rows)}")
    table = np.full((n_frames, width), np.nan)
    full = counts == width
    if full.all() and isnum.all():
        table[:] = values.reshape(n_frames, width)
    else:  # rows with gaps (empty fields) or NaN: split those rows on tabs
        lo = first[full]
        idx = lo[:, None] + np.arange(width)
        table[full] = values[idx]
        for r in np.flatnonzero(~full | ~np.logical_and.reduceat(isnum, first)):
            s = starts[first[r]]
            e = data.find(b"\n", s)
            fields = data[s:len(data) if e < 0 else e].decode("latin-1").rstrip("\r\n").split("\t")
            fields += [""] * (width - len(fields))
            if len(fields) > width and any(f.strip() for f in fields[width:]):
                raise ParseError(path, int(rows[r]), f"expected {width} fields (2 + 3 x NumMarkers), found {len(fields)}")
            try:
                table[r] = [float(f) if f.strip() else np.nan for f in fields[:width]]
            except ValueError:
                raise ParseError(path, int(rows[r]), "expected numbers, empty fields or NaN") from None
            if not np.isfinite(table[r, :2]).all():
                raise ParseError(path, int(rows[r]), "expected a frame number and a time")
    pos3 = table[:, 2:].reshape(n_frames, n_markers, 3) * UNITS_TO_METRES[units]
    pos3[~np.isfinite(pos3).all(-1)] = np.nan
    meta = file_metadata(path, data, "trc")
    meta.update(units=units, first_frame=int(table[0, 0]) if n_frames else 1, up_axis=guess_up_axis(pos3),
                up_axis_source="guessed from data", source_fps=rate, source_frames=n_frames)
    out = Markers(labels=labels, positions=pos3, fps=rate, name=path.stem, metadata=meta)
    return to_y_up(out) if y_up else out


def write_trc(markers: Markers, path: str | Path, units: str = "mm", precision: int = 10) -> None:
    """Write markers as TRC (gaps as empty fields).

    Parameters
    ----------
    markers : Markers
    path : str or Path
    units : str
        Length unit of the file (``mm``, ``cm``, ``m``, ``in``).
    precision : int
        Significant digits per value.
    """
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

    class Params(Params):
        y_up: bool = Field(False, description="rotate z-up data to y-up (default: keep the file's axes)")

    def read(self, path: str | Path) -> Any:
        return read_trc(path, y_up=self.params.y_up)

    def write(self, obj: Any, path: str | Path) -> None:
        write_trc(obj, path)
