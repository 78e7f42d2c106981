"""The parser fuzzer's oracle: the check of one mutated file (cases: :mod:`naive.mutations`)
against the reference readers of :mod:`naive.readers`.

Driver with ≥ 100,000 cases, timeouts and a report: ``benchmarks/fuzz_parsers.py``; a
short hypothesis run: ``tests/plugins/formats/test_fuzz_parsers.py``.

A case is a base (the first frames of a real AMC, BVH or TRC file, or a whole C3D file)
and one mutation. Its outcome (:func:`check`):

* ``accepted`` / ``rejected``: the reader and the reference agree (equal arrays, or
  both refuse the file), and every ParseError names the file and a line of it;
* ``crash``: the reader raised something other than ParseError;
* ``wrong_accept``: the reader accepted content the reference refuses, arrays that differ
  from the reference's, a file a mutation must break (a duplicated bone...), or, for a
  mutation that keeps the content (BOM, line ends, runs of blanks), arrays that differ
  from the unmutated file's;
* ``wrong_reject``: the reader refused a file the reference reads, or one whose content a
  mutation kept;
* ``bad_error``: a ParseError without the file's path or a valid line.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from mocapflow.framework.errors import ParseError

from . import readers as ref
from .mutations import BREAK, KINDS, SAME, Base, corpus_sources, excerpt, load_source, mutate

__all__ = [
    "BREAK",
    "KINDS",
    "SAME",
    "Base",
    "arrays",
    "check",
    "corpus_sources",
    "excerpt",
    "load_source",
    "mutate",
    "read",
    "same_arrays",
    "write_case",
]


def _close(a: np.ndarray, b: np.ndarray, atol: float) -> bool:
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.shape != b.shape or not np.array_equal(np.isnan(a), np.isnan(b)):
        return False
    ok = ~np.isnan(a)
    return bool(np.all(np.abs(a[ok] - b[ok]) <= atol * np.maximum(1.0, np.abs(b[ok]))))


def _quat_close(a: np.ndarray, b: np.ndarray) -> bool:
    if a.shape != b.shape:
        return False
    d = np.minimum(np.abs(a - b).max(-1, initial=0.0), np.abs(a + b).max(-1, initial=0.0))
    return bool((d <= 1e-9).all())


def arrays(obj) -> dict[str, np.ndarray | None]:
    """The arrays a read object is compared by."""
    from mocapflow.framework.motion import Motion

    if isinstance(obj, Motion):
        return {
            "root": obj.root_translation,
            "rot": obj.rotations,
            "local": obj.local_translations,
            "offsets": obj.skeleton.offsets,
            "fps": np.array([obj.fps]),
        }
    return {"positions": obj.positions, "fps": np.array([obj.fps])}


def same_arrays(a: dict, b: dict) -> str | None:
    """None if equal (quaternions up to sign), else the name of the first differing one."""
    for key in a:
        x, y = a[key], b.get(key)
        if (x is None) != (y is None):
            return key
        if x is None:
            continue
        if key == "rot" and not _quat_close(x, y) or key != "rot" and not _close(x, y, 1e-12):
            return key
    return None


def _reader(fmt: str):
    from mocapflow.plugins.formats.asf_amc import read_amc
    from mocapflow.plugins.formats.bvh import read_bvh
    from mocapflow.plugins.formats.c3d import read_c3d
    from mocapflow.plugins.formats.trc import read_trc

    return {"amc": read_amc, "bvh": read_bvh, "trc": read_trc, "c3d": read_c3d}[fmt]


def _compare_reference(fmt: str, data: bytes, obj) -> str | None:
    """None when the reference reader reads the same content; else why not
    (``"reject:<why>"`` when it refuses the file)."""
    try:
        if fmt == "amc":
            content = ref.read_amc(data, obj.skeleton)
            root, rot = ref.amc_arrays(content, obj.skeleton)
            if obj.n_frames != content["frames"]:
                return "frames"
            return same_arrays({"root": obj.root_translation, "rot": obj.rotations}, {"root": root, "rot": rot})
        if fmt == "bvh":
            content = ref.read_bvh(data, scale=1.0)
            root, rot, local = ref.bvh_arrays(content)
            if (
                list(obj.skeleton.names) != content["names"]
                or list(obj.skeleton.parents) != content["parents"]
                or [tuple(c) for c in obj.skeleton.channels] != content["channels"]
            ):
                return "hierarchy"
            return same_arrays(
                {
                    "root": obj.root_translation,
                    "rot": obj.rotations,
                    "local": obj.local_translations,
                    "offsets": obj.skeleton.offsets,
                    "fps": np.array([obj.metadata["frame_time"]]),
                },
                {
                    "root": root,
                    "rot": rot,
                    "local": local,
                    "offsets": content["offsets"],
                    "fps": np.array([content["frame_time"]]),
                },
            )
        if fmt == "trc":
            content = ref.read_trc(data)
            if tuple(obj.labels) != content["labels"] or obj.metadata["first_frame"] != content["first_frame"]:
                return "labels"
            return same_arrays(arrays(obj), {"positions": content["positions"], "fps": np.array([content["rate"]])})
        return None  # C3D: checked against the c3d package in _c3d_reference
    except ref.Reject as exc:
        return f"the reference refuses it: {exc}"


def _pyc3d_points(data: bytes) -> tuple[np.ndarray, bool]:
    """The c3d package's per-frame reading (T, M, 4) and whether the gaps were decided on
    the float residual word (see below)."""
    import io
    import warnings

    import c3d

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reader = c3d.Reader(io.BytesIO(data))
        pts = np.array([p[:, :4] for _, p, _ in reader.read_frames(copy=True, check_nan=False)], dtype=float)
    pts = pts.reshape(len(pts), int(reader.point_used), 4)
    if reader.point_scale < 0 and not reader._dtypes.is_dec:
        # the package casts a float file's residual word to int32, which overflows for a huge
        # positive float (1.7e38: a valid sample read as a gap); the float itself decides here
        n = 4 * int(reader.point_used)
        start = (int(reader.header.data_block) - 1) * 512
        stride = 4 * (n + int(reader.analog_used) * int(reader.analog_per_frame))
        for f in range(len(pts)):
            word = np.frombuffer(data, dtype=reader._dtypes.float32, count=n, offset=start + f * stride)
            pts[f, :, 3] = np.where(word.reshape(-1, 4)[:, 3] < 0, -1.0, 0.0)
    return pts, True


def _c3d_reference(path: Path, obj, base_data: bytes, kind: str) -> str | None:
    """The c3d package's own per-frame reader (a peer, test-only) as the reference of a
    C3D file. A truncated file the package refuses (or reads padding of) is checked against
    the package's reading of the whole file: the frames mocapflow reads are its first ones,
    and fewer than the header announces only with a warning. Other mutations the package
    refuses have no reference (accepted unverified)."""
    try:
        import c3d  # noqa: F401 - only checks that the peer reader is installed
    except ImportError:
        return None
    try:
        pts, _ = _pyc3d_points(path.read_bytes())
    except Exception:
        pts = None
    if pts is None or pts.shape[:2] != obj.positions.shape[:2]:
        if kind != "truncate":
            return None if pts is None else "shape"
        try:
            whole, _ = _pyc3d_points(base_data)
        except Exception:
            return None
        if obj.n_frames > len(whole) or whole.shape[1] != obj.positions.shape[1]:
            return "shape"
        if obj.n_frames < len(whole) and not obj.metadata.get("warnings"):
            return "frames dropped without a warning"
        pts = whole[: obj.n_frames]
    from mocapflow.plugins.formats.c3d import UNITS_TO_METRES

    unit = UNITS_TO_METRES[obj.metadata["units"]]
    want = pts[..., :3] * unit
    want[(pts[..., 3] < 0) | np.isnan(want).any(-1)] = np.nan
    return None if _close(obj.positions, want, 1e-6) else "positions"


def write_case(folder: Path, base: Base, data: bytes, asf: bytes | None) -> Path:
    """Write the case's file (and ASF, in a folder of its own per skeleton) under ``folder``."""
    if base.fmt == "amc":
        folder = folder / Path(base.asf_name).stem
        folder.mkdir(parents=True, exist_ok=True)
        a = folder / base.asf_name
        if not a.exists() or a.read_bytes() != asf:  # unchanged: the reader's ASF cache stays valid
            a.write_bytes(asf)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / base.name
    path.write_bytes(data)
    return path


def read(fmt: str, path: Path):
    """The read the oracle checks: the reader's defaults (BVH: ``scale=1.0`` and no root
    collapsing, so that values are the file's)."""
    if fmt == "bvh":
        from mocapflow.plugins.formats.bvh import read_bvh

        return read_bvh(path, scale=1.0, collapse_static_root=False)
    return _reader(fmt)(path)


def check(
    folder: Path, base: Base, kind: str, data: bytes, asf: bytes | None, reference: dict | None
) -> tuple[str, str]:
    """``(outcome, detail)`` of one mutated case (outcomes: module doc). ``reference``:
    the arrays of the unmutated base (:func:`arrays` of :func:`read`), for the
    content-keeping kinds."""
    path = write_case(folder, base, data, asf)
    try:
        if base.fmt == "bvh":  # the default settings too (automatic scale, root collapsing)
            try:
                _reader("bvh")(path)
            except ParseError as exc:
                bad = _bad_error(exc, path, base, data, asf)
                if bad:
                    return "bad_error", bad
        obj = read(base.fmt, path)
    except ParseError as exc:
        bad = _bad_error(exc, path, base, data, asf)
        if bad:
            return "bad_error", bad
        if kind in SAME:
            return "wrong_reject", f"content kept but refused: {exc}"[:300]
        if _reference_accepts(base, path, data):
            return "wrong_reject", f"the reference reads it: {exc}"[:300]
        return "rejected", str(exc)[:300]
    except Exception as exc:
        return "crash", f"{type(exc).__name__}: {exc}"[:300]
    if kind in BREAK:
        return "wrong_accept", "a duplicated or undefined bone was accepted"
    if kind in SAME and reference is not None:
        diff = same_arrays(arrays(obj), reference)
        if diff:
            return "wrong_accept", f"content-keeping mutation changed {diff}"
    # a mutated ASF has no reference reader: the AMC is then checked against the reference
    # reading it with the skeleton the ASF reader made
    why = _c3d_reference(path, obj, base.data, kind) if base.fmt == "c3d" else _compare_reference(base.fmt, data, obj)
    if why:
        return "wrong_accept", why[:300]
    return "accepted", ""


def _reference_accepts(base: Base, path: Path, data: bytes) -> bool:
    try:
        if base.fmt == "amc":
            from mocapflow.plugins.formats.asf_amc import read_asf

            ref.read_amc(data, read_asf(path.parent / base.asf_name))
        elif base.fmt == "bvh":
            ref.read_bvh(data, scale=1.0)
        elif base.fmt == "trc":
            ref.read_trc(data)
        else:
            return False
    except (ref.Reject, ParseError):
        return False
    return True


def _bad_error(exc: ParseError, path: Path, base: Base, data: bytes, asf: bytes | None) -> str | None:
    """Why a ParseError does not name the file, a line of it and what was expected."""
    asf_path = str(path.parent / base.asf_name) if base.asf_name else None
    if exc.path not in (str(path), asf_path):
        return f"names {exc.path!r}, not the file"
    if not exc.message.strip():
        return "no message"
    if base.fmt == "c3d":  # binary: no line; never a library's exception text
        foreign = re.search(r"\b[A-Z][A-Za-z]*(Error|Exception)\b", exc.message)
        return f"a foreign exception in the message: {exc.message}"[:300] if foreign else None
    text = asf if exc.path == asf_path else data
    n_lines = len(re.findall(rb"\r\n|\r|\n", text)) + 1
    if exc.line is None or not 1 <= exc.line <= n_lines:
        return f"line {exc.line} is not a line of the file ({n_lines} lines): {exc}"[:300]
    return None
