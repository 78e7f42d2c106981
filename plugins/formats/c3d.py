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
        return p.string_value.strip(" \t\r\n\x00")  # NUL padding is padding ('mm\x00\x00')
    except Exception:
        return None


def _frames_param(reader) -> int | None:
    """``POINT:FRAMES``, the number of frames (16-bit unsigned or float), when present."""
    p = reader.get("POINT:FRAMES")
    if p is None:
        return None
    try:
        v = float(p.float_value) if p.bytes_per_element == 4 else int(p.uint16_value)
    except Exception:
        return None
    return int(v) if 0 < v < 2**31 and v == int(v) else None


def _points(path: Path, data: bytes, reader, strict: bool, warn: list[str]) -> np.ndarray:
    """Raw point block, shape (T, M, 4): x, y, z in file units and the residual word
    (negative: an invalid sample)."""
    m = int(reader.point_used)
    t = int(reader.last_frame) - int(reader.first_frame) + 1
    scale = float(reader.point_scale)
    is_float = scale < 0
    word = 4 if is_float else 2
    analog_word = 4 if is_float else 2
    point_bytes = 4 * m * word
    stride = point_bytes + int(reader.analog_used) * int(reader.analog_per_frame) * analog_word
    start = (int(reader.header.data_block) - 1) * 512
    if t <= 0:
        raise ParseError(
            path, None, f"expected at least one frame, the header announces {reader.first_frame}..{reader.last_frame}"
        )
    have = (len(data) - start) // stride if stride else 0
    if have < t:
        counted = _frames_param(reader)
        announced = f"the header announces {t} frames ({reader.first_frame}..{reader.last_frame})"
        if strict or dtypes_dec(reader, is_float) or counted is None or counted > have:
            raise ParseError(path, None, f"truncated C3D: {announced}, the file holds {max(have, 0)}")
        # the data prove POINT:FRAMES right and the header's last frame wrong: read what is there
        warn.append(f"{announced} but POINT:FRAMES says {counted} and the file holds them: read {counted} frames")
        t = counted
    dtypes = reader._dtypes  # the package's byte-order description of this file
    if is_float and dtypes.is_dec:
        frames = [p[:, :4].copy() for _, p, _ in reader.read_frames(copy=True, check_nan=False)]
        raw = np.array(frames, dtype=np.float64)
        # read_frames already decoded the residual (-1 for invalid samples)
        return raw
    block = np.frombuffer(data, dtype=np.uint8, count=t * stride, offset=start).reshape(t, stride)[:, :point_bytes]
    if is_float:
        vals = np.ascontiguousarray(block).view(dtypes.float32).reshape(t, m, 4).astype(np.float64)
        # the residual word compared as a float: a huge positive one (1.7e38) is a valid
        # sample, never cast to an integer that overflows into a negative "gap"
        resid = vals[..., 3]
        valid = ~(resid < 0)
        low = np.where(valid & (resid < 2.0**31), resid, 0.0).astype(np.int64) & 0xFF
    else:
        raw = np.ascontiguousarray(block).view(dtypes.int16).reshape(t, m, 4)
        vals = raw.astype(np.float64)
        vals[..., :3] *= abs(scale)
        valid = raw[..., 3] >= 0
        low = raw[..., 3].astype(np.int64) & 0xFF
    vals[..., 3] = np.where(valid, low * abs(scale), -1.0)
    return vals


def dtypes_dec(reader, is_float: bool) -> bool:
    """Whether the file stores DEC (VAX) floats (read frame by frame by the package)."""
    return bool(is_float and reader._dtypes.is_dec)


def _check_head(path: Path, head: bytes) -> None:
    if len(head) < 512 or head[1] != 0x50:  # byte 2 of every C3D header is 0x50
        raise ParseError(path, None, "expected a C3D file (byte 2 of the header must be 0x50)")


def read_c3d(path: str | Path, y_up: bool = False, strict: bool = False) -> Markers:
    """Read the 3D points of a C3D file, rotated to y-up with ``y_up``
    (:func:`mocapflow.framework.markers.to_y_up`; default: the file's axes, recorded in
    ``metadata["up_axis"]``). Positions (T, M, 3) metres, NaN for gaps; metadata ``path``,
    ``format`` ("c3d"), ``checksum``, ``units``, ``first_frame``, ``up_axis``,
    ``up_axis_source``, ``source_fps``, ``source_frames``, ``warnings`` (what was repaired).
    ParseError for unreadable, non-C3D or truncated files (line ``None``: C3D is binary),
    also for anything the ``c3d`` package raises; ``strict``: a header contradicted by the
    data is a ParseError too, never repaired. MocapflowError without ``c3d``.
    """
    path = Path(path)
    try:
        return _read_c3d(path, y_up, strict)
    except MocapflowError:
        raise
    except Exception as exc:  # the package or numpy on a file nobody foresaw: still the file's error
        raise ParseError(
            path, None, f"expected a C3D file the reader can decode ({type(exc).__name__}: {str(exc)[:120]})"
        ) from None


def _read_c3d(path: Path, y_up: bool, strict: bool) -> Markers:
    c3d = _import_c3d()
    data = read_bytes(path, lambda head: _check_head(path, head))
    _check_head(path, data)
    warn: list[str] = []
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            reader = c3d.Reader(io.BytesIO(data))
    except Exception as exc:
        raise ParseError(
            path, None, f"expected a valid C3D header and parameter section ({type(exc).__name__}: {str(exc)[:120]})"
        ) from None
    if int(reader.point_used) <= 0:
        raise ParseError(
            path, None, "expected 3-D points (POINT:USED > 0); the file holds none (analog channels only?)"
        )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        raw = _points(path, data, reader, strict, warn)
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
    try:
        labels = tuple(str(lb).strip(" \t\r\n\x00") for lb in reader.point_labels)[: pos.shape[1]]
    except Exception:  # no POINT:LABELS (or unreadable): every point named by its index
        labels = ()
        warn.append("no readable POINT:LABELS: points named point1, point2...")
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
        warnings=warn,
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
        strict: bool = Field(False, description="refuse a header the data contradict (default: read the data, warn)")

    def read(self, path: str | Path) -> Any:
        return read_c3d(path, y_up=self.params.y_up, strict=self.params.strict)
