"""The ingest step ``formats.library``: every motion file under a folder, re-reading only the
files added or changed since the step's last output (``mocapflow index``).

Each file has a fingerprint: its size and modification time, and the SHA-1 of its bytes (an
AMC take's also covers the ASF skeletons beside it), computed only when size or time moved. A
file whose fingerprint, reader (name and version) and the step's parameters match the
previous output of the same step keeps its rows of that output (frames, clip, skeleton,
reader warnings, or its reject): nothing of it is read again. The others are read like
``formats.load`` reads them. Files no motion reader handles are rejects with the reason
(marker files name the command that reads them; ASF skeletons are read with their AMC
takes); hidden files and folders (``.name``) are left out.

Tables: those of ``formats.load`` (``data``, ``clips``, ``skeletons``, ``rejects``,
``warnings``) plus ``files``: one row per file under the folder with its fingerprint and
``status`` (``added``, ``changed``, ``unchanged`` since the previous output, or
``unsupported``: no motion reader) and ``rejected`` (unsupported, or its reader failed); the
summary counts them and the files ``removed`` since the previous output.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from pydantic import Field

from mocapflow.framework import Format, StepContext, StepOutput, schema
from mocapflow.framework import Params as BaseParams
from mocapflow.framework.datasets import Dataset
from mocapflow.framework.errors import ConfigError, PipelineError
from mocapflow.framework.motion_tables import clips_table

from .steps import _FileIngest, _read_motion_rows

#: the ``files`` table: one row per file under the folder
FILES = pa.schema(
    [
        ("path", pa.string()),
        ("size", pa.int64()),
        ("mtime_ns", pa.int64()),
        ("sha1", pa.string()),
        ("reader", pa.string()),
        ("clip_id", pa.int32()),
        ("status", pa.string()),
        ("rejected", pa.bool_()),
    ]
)


def scan(folder: Path) -> list[Path]:
    """Every file under ``folder`` (recursively, real paths, sorted), hidden names left out."""
    out: list[Path] = []
    for root, dirs, names in os.walk(folder, followlinks=False):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        out.extend(Path(root) / n for n in names if not n.startswith("."))
    return sorted(Path(os.path.realpath(p)) for p in out if os.path.isfile(p))


def _companions(path: Path) -> list[Path]:
    """Files read with ``path``: an AMC take's ASF skeletons in its folder."""
    return (
        sorted(path.parent.glob("*.asf")) + sorted(path.parent.glob("*.ASF")) if path.suffix.lower() == ".amc" else []
    )


def _stamp(path: Path) -> tuple[int, int]:
    """``(size, mtime_ns)`` of a file and its companions (sizes summed, latest time)."""
    size, mtime = 0, 0
    for p in [path, *_companions(path)]:
        st = p.stat()
        size, mtime = size + st.st_size, max(mtime, st.st_mtime_ns)
    return size, mtime


def _digest(path: Path) -> str:
    h = hashlib.sha1()
    for p in [path, *_companions(path)]:
        h.update(p.read_bytes())
    return h.hexdigest()


class LoadLibrary(Format):
    """Ingest every motion file under a folder (mixed formats, recognised by extension), reading
    again only the files added or changed since the last run.

    Tables: those of ``formats.load`` and ``files`` (each file's fingerprint and status:
    added, changed, unchanged or unsupported, and whether it was rejected); a file no motion
    reader handles is a reject naming the reason.
    """

    name = "library"
    is_step = True
    version = "2"  # 2: rotations in their own table, per clip (formats.load version 3)
    inputs: ClassVar[Mapping[str, bool]] = {}
    output_kind = "motions"

    class Params(BaseParams):
        folder: str = Field(description="folder of takes, read recursively; relative to the pipeline file")
        fps: float | None = Field(default=30.0, gt=0, description="resample every clip to this rate (Hz)")

    params: Params

    def _folder(self, base_dir: Path) -> Path:
        p = Path(self.params.folder).expanduser()
        return p if p.is_absolute() else base_dir / p

    def check_plan(self, base_dir: Path) -> list[str]:
        folder = self._folder(base_dir)
        if not folder.is_dir():
            raise ConfigError(f"folder {folder} does not exist or is not a folder")
        return []

    def source_fingerprint(self, base_dir: Path) -> str:
        h = hashlib.sha256()
        for f in scan(self._folder(base_dir)):
            try:
                st = f.stat()
                h.update(f"{f}|{st.st_size}|{st.st_mtime_ns}\n".encode())
            except OSError:
                h.update(f"{f}|missing\n".encode())
        return h.hexdigest()[:24]

    def _previous(self, ctx: StepContext) -> Dataset | None:
        """This step's last output when it was written by this component, version and parameters."""
        try:
            prev = Dataset(ctx.workspace / ctx.step_id)
            m = prev.manifest
        except Exception:  # none, or unreadable: read everything
            return None
        if m.get("component") != self.key() or str(m.get("version")) != self.version:
            return None
        if m.get("params") != self.get_params() or not prev.has_table("files"):
            return None
        return prev

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        folder = self._folder(ctx.base_dir)
        readers: dict[str, Any] = {}  # extension -> format class
        others: dict[str, Any] = {}
        for _, fmt in ctx.registries["formats"]:
            for ext in fmt.extensions:
                target = readers if getattr(fmt, "produces", "") == "motion" else others
                target.setdefault(ext.lower(), fmt)
        files = scan(folder)
        prev = self._previous(ctx)
        old = {r["path"]: r for r in prev.table("files").to_pylist()} if prev is not None else {}

        motion_files = [f for f in files if f.suffix.lower() in readers]
        ids = dict(zip(motion_files, _FileIngest.clip_ids(motion_files), strict=True)) if motion_files else {}
        file_rows: list[dict[str, Any]] = []
        rejects: list[tuple[Any, ...]] = []
        jobs: list[tuple[Any, ...]] = []
        reuse: dict[Path, dict[str, Any]] = {}  # file -> its old files row (rows kept)
        for f in files:
            ext = f.suffix.lower()
            cls = readers.get(ext)
            if cls is None:
                other = others.get(ext)
                if other is not None and other.produces == "skeleton":
                    continue  # read with the motions that use it (ASF beside AMC)
                if other is not None and other.produces == "markers":
                    why = f"marker data ({other.name}): not a skeleton motion; `mocapflow reconstruct` reads it"
                else:
                    known = ", ".join(sorted(readers))
                    why = f"no motion reader for {ext or 'files without an extension'!r} (motion files: {known})"
                st = f.stat()
                file_rows.append(
                    {"path": str(f), "size": st.st_size, "mtime_ns": st.st_mtime_ns, "sha1": "", "reader": ""}
                )
                file_rows[-1].update(clip_id=None, status="unsupported", rejected=True)
                rejects.append((None, str(f), None, why))
                continue
            size, mtime = _stamp(f)
            reader = f"{cls.key()}@{cls.version}"
            before = old.get(str(f))
            if (
                before is not None
                and before["reader"] == reader
                and (before["size"], before["mtime_ns"])
                == (
                    size,
                    mtime,
                )
            ):
                sha1 = before["sha1"]
            else:
                sha1 = _digest(f)
            row = {"path": str(f), "size": size, "mtime_ns": mtime, "sha1": sha1, "reader": reader, "clip_id": ids[f]}
            row["rejected"] = False
            if before is not None and before["reader"] == reader and before["sha1"] == sha1:
                reuse[f] = before
                row["status"] = "unchanged"
            else:
                row["status"] = "changed" if before is not None else "added"
                jobs.append((cls, {}, str(f), self.params.fps, ids[f]))
            file_rows.append(row)
        if not motion_files:
            raise PipelineError(f"no motion file under {folder} (motion files: {', '.join(sorted(readers))})")

        results = ctx.map(_read_motion_rows, jobs, desc=f"{ctx.step_id}: reading") if jobs else []
        fresh: dict[str, Any] = {job[2]: r for job, r in zip(jobs, results, strict=True)}
        kept = _kept_rows(prev, {str(f): (before["clip_id"], ids[f]) for f, before in reuse.items()})

        frames: list[pa.Table] = []
        rotations: list[pa.Table] = []
        clips: list[dict[str, Any]] = []
        warnings: list[dict[str, Any]] = []
        skeletons: dict[str, dict[str, Any]] = {}
        status = {r["path"]: r for r in file_rows}
        for f in motion_files:
            p = str(f)
            got = fresh.get(p)
            if got is None:
                got = kept.get(p)
            if got is None or isinstance(got, tuple):  # a reject, read now or kept
                line, msg = (got[1], got[2]) if isinstance(got, tuple) else (None, "unreadable")
                rejects.append((ids[f], p, line, msg))
                status[p]["rejected"] = True
                continue
            frames.append(got["frames"])
            rotations.append(got["rotations"])
            clips.append(got["clip"])
            warnings.extend({"clip_id": ids[f], "path": p, "line": None, "message": w} for w in got["warnings"])
            key, sk_name, n_joints, definition = got["skeleton"]
            skeletons.setdefault(
                key, {"skeleton": key, "name": sk_name, "n_joints": n_joints, "definition": definition}
            )
        removed = sorted(set(old) - set(status))
        tables = {
            "data": pa.concat_tables(frames) if frames else schema.motion_frames().empty_table(),
            "rotations": pa.concat_tables(rotations) if rotations else schema.motion_rotations().empty_table(),
            "clips": clips_table(clips),
            "skeletons": pa.Table.from_pylist(list(skeletons.values()), schema=schema.SKELETONS),
            "rejects": _FileIngest._rejects_table(rejects),
            "warnings": pa.Table.from_pylist(warnings, schema=schema.REJECTS),
            "files": pa.Table.from_pylist(file_rows, schema=FILES),
        }
        counts = {s: sum(r["status"] == s for r in file_rows) for s in ("added", "changed", "unchanged", "unsupported")}
        summary = {
            "files": len(files),
            "clips": len(clips),
            "frames": int(sum(c["n_frames"] for c in clips)),
            "read": len(jobs),
            **counts,
            "removed": len(removed),
            "rejects": len(rejects),
            "warnings": len(warnings),
        }
        return StepOutput(tables, summary)


def _kept_rows(prev: Dataset | None, keep: Mapping[str, tuple[int, int]]) -> dict[str, Any]:
    """The rows of the previous output of the files in ``keep`` (path -> (old id, new id)),
    as :func:`_read_motion_rows` returns them, their clip ids changed to the new ones: a
    previous reject comes back as ``(path, line, message)``."""
    if prev is None or not keep:
        return {}
    out: dict[str, Any] = {}
    rej = prev.table("rejects").to_pylist()
    for r in rej:
        if r["path"] in keep:
            out[r["path"]] = (r["path"], r["line"], r["message"])
    old_clips = {r["clip_id"]: r for r in prev.table("clips").to_pylist()}
    sk = {r["skeleton"]: r for r in prev.table("skeletons").to_pylist()}
    warn: dict[str, list[str]] = {}
    for r in prev.table("warnings").to_pylist():
        warn.setdefault(r["path"], []).append(r["message"])
    wanted = {old for p, (old, _) in keep.items() if p not in out and old in old_clips}
    if not wanted:
        return out
    rot = prev.table("rotations")
    rot = rot.filter(pc.is_in(rot["clip_id"], pa.array(sorted(wanted), pa.int32())))
    rot_of = {int(c): i for i, c in enumerate(rot["clip_id"].to_pylist())}
    data = prev.table("data")
    data = data.filter(pc.is_in(data["clip_id"], pa.array(sorted(wanted), pa.int32())))
    cid = data["clip_id"].to_numpy()
    order = np.argsort(cid, kind="stable")
    data = data.take(pa.array(order))
    cid = cid[order]
    for path, (old, new) in keep.items():
        if path in out or old not in old_clips:
            continue
        a, b = np.searchsorted(cid, [old, old + 1])
        rows = data.slice(int(a), int(b - a))
        rows = rows.set_column(0, "clip_id", pa.array(np.full(rows.num_rows, new, np.int32)))
        r = rot.slice(rot_of[old], 1)
        r = r.set_column(0, "clip_id", pa.array([new], pa.int32()))
        clip = {**old_clips[old], "clip_id": new}
        s = sk[clip["skeleton"]]
        out[path] = {
            "frames": rows,
            "rotations": r,
            "clip": clip,
            "warnings": warn.get(path, []),
            "skeleton": (s["skeleton"], s["name"], s["n_joints"], s["definition"]),
        }
    return out


__all__ = ["FILES", "LoadLibrary", "scan"]
