"""C3D marker files, read with the pure-Python ``c3d`` package (optional extra ``c3d``).

The ``c3d`` package parses the header and parameter section; the point data are then read
in one vectorised step (the package itself loops over frames): the data section is viewed
as a ``(T, frame_bytes)`` array whose point part is reinterpreted as float32 or int16
(times ``POINT:SCALE``) in the file's byte order. Files with DEC (VAX) floats fall back to
the package's per-frame reader.

* Units: ``POINT:UNITS`` (``mm``, ``cm``, ``m``, ``in``) converted to metres.
* Gaps: a sample whose fourth word (residual) is negative is NaN. A valid sample whose
  coordinates are not finite or lie beyond 10 km is a ParseError (the value policy of
  :mod:`._common`), as is a ``POINT:RATE`` outside (0, 100 kHz].
* Labels: ``POINT:LABELS`` stripped of padding.
* Axes: kept as in the file. ``metadata["up_axis"]`` (``"+z"``...) takes its axis from
  ``POINT:Y_SCREEN`` when present, else the axis along which the marker cloud spreads most
  (median over frames; right for people standing or walking); its sign is the side of 0
  where the markers lie (``Y_SCREEN`` signs are unreliable in real files).
  ``metadata["up_axis_source"]`` says which. ``read_c3d(path, y_up=True)`` rotates to y-up.
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from pydantic import Field

from mocapflow.framework.components import Format, Params
from mocapflow.framework.errors import MocapflowError, ParseError
from mocapflow.framework.markers import Markers, guess_up_axis, to_y_up

from ._common import MAX_FPS, MAX_METRES, file_metadata, read_bytes

__all__ = ["C3dFormat", "read_c3d", "UNITS_TO_METRES"]

#: Length units of ``POINT:UNITS`` (lower case) -> metres.
UNITS_TO_METRES: dict[str, float] = {"mm": 0.001, "cm": 0.01, "m": 1.0, "in": 0.0254, "inch": 0.0254, "dm": 0.1}


def _import_c3d():
    try:
        import c3d
    except ImportError:
        raise MocapflowError("reading C3D files needs the optional 'c3d' package: pip install mocapflow[c3d]") from None
    return c3d


def _param(reader, key: str) -> str | None:
    p = reader.get(key)
    if p is None:
        return None
    try:
        return p.string_value.strip()
    except Exception:
        return None


def _points(path: Path, data: bytes, reader) -> np.ndarray:
    """Raw point block, shape (T, M, 4): x, y, z in file units and the residual word."""
    m = int(reader.point_used)
    t = int(reader.last_frame) - int(reader.first_frame) + 1
    scale = float(reader.point_scale)
    is_float = scale < 0
    word = 4 if is_float else 2
    analog_word = 4 if is_float else 2
    point_bytes = 4 * m * word
    stride = point_bytes + int(reader.analog_used) * int(reader.analog_per_frame) * analog_word
    start = (int(reader.header.data_block) - 1) * 512
    if t <= 0 or m <= 0:
        return np.zeros((max(t, 0), m, 4))
    have = (len(data) - start) // stride if stride else 0
    if have < t:
        raise ParseError(
            path,
            None,
            f"truncated C3D: the header announces {t} frames "
            f"({reader.first_frame}..{reader.last_frame}), the file holds {max(have, 0)}",
        )
    dtypes = reader._dtypes  # the package's byte-order description of this file
    if is_float and dtypes.is_dec:
        frames = [p[:, :4].copy() for _, p, _ in reader.read_frames(copy=True, check_nan=False)]
        raw = np.array(frames, dtype=np.float64)
        # read_frames already decoded the residual (-1 for invalid samples)
        return raw
    block = np.frombuffer(data, dtype=np.uint8, count=t * stride, offset=start).reshape(t, stride)[:, :point_bytes]
    if is_float:
        vals = np.ascontiguousarray(block).view(dtypes.float32).reshape(t, m, 4).astype(np.float64)
        resid = vals[..., 3].astype(np.int32)
    else:
        raw = np.ascontiguousarray(block).view(dtypes.int16).reshape(t, m, 4)
        vals = raw.astype(np.float64)
        vals[..., :3] *= abs(scale)
        resid = raw[..., 3].astype(np.int32)
    out = vals.copy()
    out[..., 3] = np.where(resid < 0, -1.0, (resid & 0xFF) * abs(scale))
    return out


def read_c3d(path: str | Path, y_up: bool = False) -> Markers:
    """Read the 3D points of a C3D file, rotated to y-up with ``y_up``
    (:func:`mocapflow.framework.markers.to_y_up`; default: the file's axes, recorded in
    ``metadata["up_axis"]``). Positions (T, M, 3) metres, NaN for gaps; metadata ``path``,
    ``format`` ("c3d"), ``checksum``, ``units``, ``first_frame``, ``up_axis``,
    ``up_axis_source``, ``source_fps``, ``source_frames``. ParseError for unreadable, non-C3D
    or truncated files (line ``None``: C3D is binary); MocapflowError without ``c3d``.
    """
    c3d = _import_c3d()
    path = Path(path)
    data = read_bytes(path)
    if len(data) < 512 or data[1] != 0x50:  # byte 2 of every C3D header is 0x50
        raise ParseError(path, None, "expected a C3D file (byte 2 of the header must be 0x50)")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            reader = c3d.Reader(io.BytesIO(data))
            raw = _points(path, data, reader)
    except ParseError:
        raise
    except Exception as exc:
        raise ParseError(path, None, f"expected a valid C3D header and parameter section ({exc})") from None
    units = (_param(reader, "POINT:UNITS") or "mm").lower()
    if units not in UNITS_TO_METRES:
        raise ParseError(path, None, f"expected POINT:UNITS among {sorted(UNITS_TO_METRES)}, found {units!r}")
    rate = float(reader.point_rate)
    if not 0 < rate <= MAX_FPS:
        raise ParseError(path, None, f"expected a POINT:RATE in (0, {MAX_FPS:g}] Hz, found {rate:g}")
    with np.errstate(over="ignore", invalid="ignore"):
        pos = raw[..., :3] * UNITS_TO_METRES[units]
        gap = raw[..., 3] < 0
        wrong = ~gap & ~(np.abs(pos) <= MAX_METRES).all(-1)  # non-finite or beyond 10 km
    if wrong.any():
        f, m = np.argwhere(wrong)[0]
        raise ParseError(
            path,
            None,
            f"frame {int(reader.first_frame) + int(f)}, point {int(m) + 1}: expected a "
            f"finite position within {MAX_METRES:g} m or an invalid sample (negative residual), "
            f"found {pos[f, m].tolist()}",
        )
    pos[gap] = np.nan
    labels = tuple(str(lb).strip() for lb in reader.point_labels)[: pos.shape[1]]
    # files with fewer POINT:LABELS than points exist; name the rest by index
    labels += tuple(f"point{k + 1}" for k in range(len(labels), pos.shape[1]))
    # Y_SCREEN names the vertical axis, but its sign is unreliable in real files (Qualisys
    # and numediart say "-Z" with the floor at z = 0 and people above it): sign from data
    y_screen = (_param(reader, "POINT:Y_SCREEN") or "").lower()
    letter = y_screen[-1] if y_screen[-1:] in ("x", "y", "z") else None
    up = guess_up_axis(pos, letter)
    source = "POINT:Y_SCREEN axis, sign from data" if letter else "guessed from data"
    meta = file_metadata(path, data, "c3d")
    meta.update(
        units=units,
        first_frame=int(reader.first_frame),
        up_axis=up,
        up_axis_source=source,
        source_fps=rate,
        source_frames=int(pos.shape[0]),
    )
    out = Markers(labels=labels, positions=pos, fps=rate, name=path.stem, metadata=meta)
    return to_y_up(out) if y_up else out


class C3dFormat(Format):
    """C3D marker trajectories (needs the optional ``c3d`` package)."""

    name: ClassVar[str] = "c3d"
    extensions: ClassVar[tuple[str, ...]] = (".c3d",)
    produces: ClassVar[str] = "markers"

    class Params(Params):
        y_up: bool = Field(False, description="rotate the markers to y-up (default: keep the file's axes)")

    def read(self, path: str | Path) -> Any:
        return read_c3d(path, y_up=self.params.y_up)
