"""C3D marker files, read with the pure-Python ``c3d`` package (optional extra ``c3d``).

The ``c3d`` package parses the header and parameter section; the point data are then read
in one vectorised step (the package itself loops over frames): the data section is viewed
as a ``(T, frame_bytes)`` array whose point part is reinterpreted as float32 or int16
(times ``POINT:SCALE``) in the file's byte order. Files with DEC (VAX) floats fall back to
the package's per-frame reader.

* Units: ``POINT:UNITS`` (``mm``, ``cm``, ``m``, ``in``) converted to metres.
* Gaps: a sample whose fourth word (residual) is negative is NaN (compared as a float in
  float files: a huge positive residual is a valid sample, never an overflowed cast). A valid sample whose
  coordinates are not finite or lie beyond 10 km is a ParseError (the value policy of
  :mod:`._common`), as is a ``POINT:RATE`` outside (0, 100 kHz].
* Labels: ``POINT:LABELS`` stripped of padding (spaces, NUL); a file without them names its
  points ``point1``... (with a warning). ``POINT:UNITS`` may be NUL-padded (``mm\0\0``).
* Frames: the header's first..last frame. When the file holds fewer, but exactly the
  ``POINT:FRAMES`` it announces too, those are read and ``metadata["warnings"]`` says so
  (``strict=True``: refused as truncated). A file without 3-D points (analog channels
  only) is a ParseError, as is anything the ``c3d`` package raises (the file named).
* Axes: kept as in the file. ``metadata["up_axis"]`` (``"+z"``...) takes its axis from
  ``POINT:Y_SCREEN`` when present, else the axis along which the marker cloud spreads most
  (median over frames; right for people standing or walking); its sign is the side of 0
  where the markers lie (``Y_SCREEN`` signs are unreliable in real files).
  ``metadata["up_axis_source"]`` says which. ``read_c3d(path, y_up=True)`` rotates to y-up.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from pydantic import Field

from mocapflow.framework.components import Format
from mocapflow.framework.components import Params as BaseParams
from mocapflow.framework.errors import MocapflowError, ParseError
from mocapflow.framework.markers import Markers, guess_up_axis, to_y_up

from ._c3d_parse import C3dError, C3dFile, parse_c3d
from ._common import MAX_FPS, MAX_METRES, file_metadata, read_bytes

__all__ = ["C3dFormat", "read_c3d", "UNITS_TO_METRES"]

#: Length units of ``POINT:UNITS`` (lower case) -> metres.
UNITS_TO_METRES: dict[str, float] = {"mm": 0.001, "cm": 0.01, "m": 1.0, "in": 0.0254, "inch": 0.0254, "dm": 0.1}
#: Spelled-out ``POINT:UNITS`` (some writers cut them to the parameter's 4 characters:
#: ``mete``) -> the unit.
UNIT_NAMES: dict[str, str] = {
    **{w: "m" for w in ("mete", "meter", "meters", "metre", "metres")},
    **{w: "mm" for w in ("mill", "millimeter", "millimeters", "millimetre", "millimetres")},
    **{w: "cm" for w in ("cent", "centimeter", "centimeters", "centimetre", "centimetres")},
    "inches": "in",
}


def _check_head(path: Path, head: bytes) -> None:
    if len(head) < 512 or head[1] != 0x50:  # byte 2 of every C3D header is 0x50
        raise ParseError(path, None, "expected a C3D file (byte 2 of the header must be 0x50)")


def read_c3d(path: str | Path, y_up: bool = False, strict: bool = False) -> Markers:
    """Read the 3D points of a C3D file, rotated to y-up with ``y_up``
    (:func:`mocapflow.framework.markers.to_y_up`; default: the file's axes, recorded in
    ``metadata["up_axis"]``). Positions (T, M, 3) metres, NaN for gaps; metadata ``path``,
    ``format`` ("c3d"), ``checksum``, ``units``, ``first_frame``, ``up_axis``,
    ``up_axis_source``, ``source_fps``, ``source_frames``, ``processor``,
    ``analog_channels`` / ``analog_rate`` (what else the file holds), ``warnings`` (what was
    repaired). ParseError for unreadable, non-C3D, analog-only or empty files (line ``None``:
    C3D is binary); ``strict``: a header contradicted by the data is a ParseError too,
    never repaired.
    """
    path = Path(path)
    try:
        return _read_c3d(path, y_up, strict)
    except MocapflowError:
        raise
    except Exception:  # numpy on a file nobody foresaw: still the file's error, no foreign text
        raise ParseError(
            path, None, "expected a C3D layout the reader knows; this one it cannot decode (please report the file)"
        ) from None


def _analog_summary(f: C3dFile) -> tuple[int, float, list[str]]:
    n = f.analog_channels
    rate = f.number("ANALOG:RATE")
    if rate is None or not np.isfinite(rate) or rate <= 0:
        rate = f.point_rate * f.analog_per_frame
    return n, float(rate), f.labels("ANALOG", n)


def _whole_frames(f: C3dFile, held: int) -> int:
    """``held`` less the trailing frames of zero bytes: the last 512-byte block is padded
    with zeros, and such frames are padding, not samples at the origin."""
    block = f.frame_block(held)
    while held and not block[held - 1].any():
        held -= 1
    return held


def _frame_count(path: Path, f: C3dFile, strict: bool, warn: list[str]) -> int:
    """The frames to read: those the header announces, or the whole frames the file holds
    when it holds fewer (with a warning naming both; ``strict``: a ParseError). A header
    whose 16-bit frame fields cannot count the frames (last < first, or 65535: takes over
    65,535 frames) is read through ``TRIAL:ACTUAL_*_FIELD`` or ``POINT:FRAMES``, else as the
    whole frames held, with a warning."""
    announced = f.frames_announced()
    held = f.frames_held()
    counted = f.point_frames()
    if announced is None or announced <= 0:
        whole = _whole_frames(f, held)
        what = f"the header's frames {f.first_frame}..{f.last_frame} count no frames and no parameter does"
        if strict or whole == 0:
            raise ParseError(path, None, f"expected at least one frame: {what}; the file holds {whole} whole frames")
        warn.append(f"{what}: read the {whole} whole frames the file holds")
        return whole
    what = f"the header announces {announced} frames ({f.first_frame}..{f.last_frame})"
    if held >= announced:
        return announced
    held = _whole_frames(f, held)
    if strict or held == 0:
        raise ParseError(path, None, f"truncated C3D: {what}, the file holds {held} whole frames")
    pf = "" if counted is None or counted == announced else f", POINT:FRAMES {counted}"
    warn.append(f"{what}{pf}, the file holds {held} whole frames: read {held}")
    return held


def _read_c3d(path: Path, y_up: bool, strict: bool) -> Markers:
    data = read_bytes(path, lambda head: _check_head(path, head))
    _check_head(path, data)
    try:
        f = parse_c3d(data)
    except C3dError as exc:
        raise ParseError(path, None, str(exc)) from None
    warn = list(f.warnings)
    if f.points <= 0:
        n, rate, names = _analog_summary(f)
        if n:
            shown = ", ".join(names[:8]) + (", ..." if len(names) > 8 else "")
            raise ParseError(
                path,
                None,
                f"expected 3-D points; the file holds none, only {n} analog channels at {rate:g} Hz"
                + (f" ({shown})" if shown else ""),
            )
        rot = f.get("ROTATION:USED")
        if rot is not None and rot.kind in (1, 2) and rot.data and int(rot.uint16()[0]) > 0:
            raise ParseError(
                path,
                None,
                f"expected 3-D points; the file holds none, only {int(rot.uint16()[0])} rotations (ROTATION)",
            )
        raise ParseError(path, None, "expected 3-D points; the file holds none (POINT:USED 0, no analog channels)")
    if f.processor == "dec" and f.float_data:
        pass  # VAX floats: decoded by the parser
    t = _frame_count(path, f, strict, warn)
    raw = f.read_points(t)
    units = (f.string("POINT:UNITS") or "mm").lower()
    units = UNIT_NAMES.get(units, units)
    if units not in UNITS_TO_METRES:
        raise ParseError(path, None, f"expected POINT:UNITS among {sorted(UNITS_TO_METRES)}, found {units!r}")
    rate = float(f.point_rate)
    if not 0 < rate <= MAX_FPS:
        raise ParseError(path, None, f"expected a POINT:RATE in (0, {MAX_FPS:g}] Hz, found {rate:g}")
    with np.errstate(over="ignore", invalid="ignore"):
        pos = raw[..., :3] * UNITS_TO_METRES[units]
        gap = raw[..., 3] < 0
        # NaN coordinates in a float file are how several writers (Vicon Nexus, kinetics
        # toolkit) mark a missing sample whatever its residual: a gap, counted in a warning
        nan = ~gap & np.isnan(pos).any(-1) if f.float_data else np.zeros_like(gap)
    if nan.any():
        warn.append(f"{int(nan.sum())} samples with NaN coordinates and a valid residual: read as gaps")
        gap |= nan
    with np.errstate(over="ignore", invalid="ignore"):
        wrong = ~gap & ~(np.abs(pos) <= MAX_METRES).all(-1)  # non-finite or beyond 10 km
    if wrong.any():
        fr, m = np.argwhere(wrong)[0]
        raise ParseError(
            path,
            None,
            f"frame {f.first_frame + int(fr)}, point {int(m) + 1}: expected a "
            f"finite position within {MAX_METRES:g} m or an invalid sample (negative residual), "
            f"found {pos[fr, m].tolist()}",
        )
    pos[gap] = np.nan
    labels = tuple(f.labels("POINT", pos.shape[1]))
    if not labels and f.get("POINT:LABELS") is None:
        warn.append("no POINT:LABELS: points named point1, point2...")
    # files with fewer POINT:LABELS than points exist; name the rest by index
    labels += tuple(f"point{k + 1}" for k in range(len(labels), pos.shape[1]))
    # Y_SCREEN names the vertical axis, but its sign is unreliable in real files (Qualisys
    # and numediart say "-Z" with the floor at z = 0 and people above it): sign from data
    y_screen = (f.string("POINT:Y_SCREEN") or "").lower()
    letter = y_screen[-1] if y_screen[-1:] in ("x", "y", "z") else None
    up = guess_up_axis(pos, letter)
    source = "POINT:Y_SCREEN axis, sign from data" if letter else "guessed from data"
    n_analog, analog_rate, _names = _analog_summary(f)
    meta = file_metadata(path, data, "c3d")
    meta.update(
        units=units,
        first_frame=int(f.first_frame),
        up_axis=up,
        up_axis_source=source,
        source_fps=rate,
        source_frames=int(pos.shape[0]),
        processor=f.processor,
        analog_channels=n_analog,
        analog_rate=analog_rate if n_analog else 0.0,
        warnings=warn,
    )
    out = Markers(labels=labels, positions=pos, fps=rate, name=path.stem, metadata=meta)
    return to_y_up(out) if y_up else out


class C3dFormat(Format):
    """C3D marker trajectories (a NumPy parser: Intel, DEC and SGI/MIPS files, int16 or float)."""

    name: ClassVar[str] = "c3d"
    extensions: ClassVar[tuple[str, ...]] = (".c3d",)
    produces: ClassVar[str] = "markers"

    class Params(BaseParams):
        y_up: bool = Field(False, description="rotate the markers to y-up (default: keep the file's axes)")
        strict: bool = Field(False, description="refuse a header the data contradict (default: read the data, warn)")

    params: Params

    def read(self, path: str | Path) -> Any:
        return read_c3d(path, y_up=self.params.y_up, strict=self.params.strict)
