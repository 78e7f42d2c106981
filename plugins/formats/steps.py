"""The ingest step ``formats.load`` and the export step ``formats.export``.

Readers are looked up in the ``formats`` registry by file extension, so a third-party
format plugin is picked up by ingest without any change here.
"""

from __future__ import annotations

import glob
import hashlib
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar, Literal, cast

import numpy as np
import pyarrow as pa
from pydantic import Field

from mocapflow.framework import Format, Markers, Motion, ParseError, StepContext, StepOutput, schema
from mocapflow.framework import Params as BaseParams
from mocapflow.framework.datasets import Dataset
from mocapflow.framework.errors import ConfigError, DataError, MocapflowError, PipelineError
from mocapflow.framework.joints import missing_required
from mocapflow.framework.motion_tables import clip_row, clips_table, frames_table, rotations_table
from mocapflow.framework.normalize import resample
from mocapflow.framework.workspace import MANIFEST


def _glob(pattern: str, base: Path) -> list[str]:
    """Real paths of the files a glob pattern (``**`` recursive) matches, relative to ``base``."""
    p = Path(pattern).expanduser()
    # os.path.realpath on strings: Path.resolve cost more than the glob itself (201 files: 17 ms)
    return [
        os.path.realpath(h)
        for h in glob.glob(str(p if p.is_absolute() else base / p), recursive=True)
        if os.path.isfile(h) or not os.path.exists(h)
    ]


def _expand(patterns: list[str], base: Path, exclude: list[str]) -> list[Path]:
    """Files matched by glob patterns (``**`` recursive), sorted, without duplicates."""
    found = {h for pat in patterns for h in _glob(pat, base)}
    excluded = set()
    for pat in exclude:
        p = Path(pat).expanduser()
        excluded |= {os.path.realpath(h) for h in glob.glob(str(p if p.is_absolute() else base / p), recursive=True)}
    return [Path(k) for k in sorted(found - excluded)]


def _prepare_motion(motion: Motion, path: str, fps: float | None) -> Motion | tuple[str, int | None, str]:
    """Check the canonical joints, complete the metadata and resample one read motion."""
    missing = missing_required(motion.skeleton.canonical)
    if missing:
        return (
            path,
            None,
            f"skeleton lacks required joints {', '.join(missing)} (add its naming dialect from a plugin: the register_joint_maps hook)",
        )
    if "checksum" not in motion.metadata:
        motion.metadata["checksum"] = hashlib.sha1(Path(path).read_bytes()).hexdigest()
    motion.metadata.setdefault("path", path)
    motion.metadata.setdefault("source_fps", motion.fps)
    motion.metadata.setdefault("source_frames", motion.n_frames)
    return resample(motion, fps) if fps else motion


def _read_file(
    job: tuple[type[Format], dict[str, Any], str, float | None],
) -> Motion | Markers | tuple[str, int | None, str]:
    """Read one file (motions are also checked and resampled to ``fps``); a failure comes
    back as ``(path, line, message)``. Module-level so that process pools can pickle it."""
    cls, params, path, fps = job
    expected = Motion if cls.produces == "motion" else Markers
    try:
        obj = cls(params).read(path)
        if not isinstance(obj, expected):
            return (path, None, f"{cls.key()} produced {type(obj).__name__}, not {expected.__name__}")
        return _prepare_motion(obj, path, fps) if isinstance(obj, Motion) else obj
    except ParseError as exc:
        return (exc.path, exc.line, exc.message)
    except MocapflowError as exc:
        return (path, None, str(exc))
    except (OSError, ValueError) as exc:
        return (path, None, f"{type(exc).__name__}: {exc}")


def _read_motion_rows(
    job: tuple[type[Format], dict[str, Any], str, float | None, int],
) -> tuple[Any, ...] | dict[str, Any]:
    """Read one motion file and turn it into its rows of the motions dataset, in the worker:
    ``{"frames": its frame rows (Arrow, float32), "clip": its clips row, "skeleton": (key,
    name, n_joints, JSON definition)}``, or a reject ``(path, line, message)``.

    What travels back is the compact on-disk form (float32 Arrow buffers, half the bytes of
    a pickled float64 motion), and the client only concatenates: building the tables (0.42 s
    of the client's serial time for the corpus) runs in the workers.
    """
    cls, params, path, fps, clip_id = job
    motion = _read_file((cls, params, path, fps))
    if isinstance(motion, tuple):
        return motion
    assert isinstance(motion, Motion)  # a motion reader's (_read_file checked what it produced)
    s = motion.skeleton
    return {
        "warnings": list(motion.metadata.get("warnings") or []),
        "frames": frames_table(clip_id, motion),
        "rotations": rotations_table(clip_id, motion),
        "clip": clip_row(clip_id, motion),
        "skeleton": (s.fingerprint(), s.name, s.n_joints, json.dumps(s.to_dict())),
    }


class _FileIngest(Format):
    """Shared machinery of the ingest steps: globbing, reader lookup by extension in the
    ``formats`` registry, per-file fan-out with failures collected as rejects, fingerprints."""

    is_step = True
    version = "2"  # 2: clip ids keyed by folder and file name (schema.clip_keys)
    inputs: ClassVar[Mapping[str, bool]] = {}
    #: which readers the step uses: those whose ``produces`` equals this
    reads: ClassVar[str] = "motion"

    class Params(BaseParams):
        paths: list[str] = Field(
            min_length=1, description="glob patterns (** recursive), relative to the pipeline file"
        )
        exclude: list[str] = Field(default_factory=list, description="glob patterns of files to leave out")
        on_error: Literal["record", "fail"] = Field("record", description="record bad files in `rejects`, or stop")
        readers: dict[str, dict[str, Any]] = Field(
            default_factory=dict, description="per-format reader parameters, e.g. {amc: {fps: 120}}"
        )
        labels: str | None = Field(
            None, description="CSV of clip labels (clip,label[,start,end] in seconds), relative to the pipeline file"
        )
        label_pattern: str | None = Field(
            None, description="regular expression over clip names giving a clip's label (group 'label')"
        )

    params: Params

    def _files(self, base: Path) -> list[Path]:
        """The input files; the listing :meth:`source_fingerprint` made is reused once, by
        the run that follows it (the runner fingerprints every step before running it), so
        the files read are the files fingerprinted, and a run lists its inputs once."""
        listed = self.__dict__.pop("_listed", None)
        if listed is not None and listed[0] == str(base):
            return cast("list[Path]", listed[1])
        return _expand(self.params.paths, base, self.params.exclude)

    def check_plan(self, base_dir: Path) -> list[str]:
        if self.params.labels is not None and not self._labels_path(base_dir).is_file():
            raise ConfigError(f"labels file {self._labels_path(base_dir)} does not exist")
        if self.params.label_pattern is not None:
            from mocapflow.framework.labels import pattern_labels

            pattern_labels(self.params.label_pattern, [])  # a bad expression fails here, not after reading
        return [
            f"pattern {pat!r} of `paths` matches no file (relative to {base_dir})"
            for pat in self.params.paths
            if not _glob(pat, base_dir)
        ]

    def source_fingerprint(self, base_dir: Path) -> str:
        h = hashlib.sha256()
        skeletons: dict[Path, list[Path]] = {}  # one listing per folder, not one per take
        files = _expand(self.params.paths, base_dir, self.params.exclude)  # always afresh: this is the check
        self.__dict__["_listed"] = (str(base_dir), files)
        for f in files:
            # AMC readers also read the skeleton files beside the motions (.asf)
            if f.suffix.lower() == ".amc" and f.parent not in skeletons:
                skeletons[f.parent] = sorted(f.parent.glob("*.asf"))
            for g in [f, *skeletons[f.parent]] if f.suffix.lower() == ".amc" else [f]:
                try:
                    st = g.stat()
                    h.update(f"{g}|{st.st_size}|{st.st_mtime_ns}\n".encode())
                except OSError:
                    h.update(f"{g}|missing\n".encode())
        if self.params.labels is not None:  # the labels CSV is an input too
            f = self._labels_path(base_dir)
            h.update(f.read_bytes() if f.is_file() else b"missing")
        return h.hexdigest()[:24]

    def _labels_path(self, base_dir: Path) -> Path:
        p = Path(self.params.labels or "").expanduser()
        return p if p.is_absolute() else base_dir / p

    def _labels(self, clips: list[dict[str, Any]], base_dir: Path) -> dict[str, pa.Table]:
        """``{"labels": table}`` from the ``labels`` CSV and ``label_pattern``, or ``{}``."""
        from mocapflow.framework.labels import labels_table

        csv = self._labels_path(base_dir) if self.params.labels is not None else None
        table = labels_table(clips, csv, self.params.label_pattern)
        return {} if table is None else {"labels": table}

    @staticmethod
    def clip_ids(files: list[Path]) -> list[int]:
        """Stable clip id of each file: :func:`~mocapflow.framework.schema.clip_ids_of` its
        :func:`~mocapflow.framework.schema.clip_keys` key (folder and name, ``02/02_01.amc``),
        so the id depends neither on which other files match or parse, nor on the patterns
        or where the pipeline is: two ingests of one take give it one id."""
        return schema.clip_ids_of(schema.clip_keys([os.path.realpath(f) for f in files]))

    def _jobs(self, ctx: StepContext, fps: float | None) -> tuple[list[tuple[Any, ...]], list[int], int]:
        """``(read jobs, their clip ids, files listed)``: one job per file a reader handles."""
        by_ext: dict[str, type[Format]] = {}
        for _, cls in ctx.registries["formats"]:
            if getattr(cls, "produces", "") == self.reads:
                for ext in cls.extensions:
                    by_ext.setdefault(ext.lower(), cls)
        files = self._files(ctx.base_dir)
        jobs = [
            (by_ext[f.suffix.lower()], self.params.readers.get(by_ext[f.suffix.lower()].name, {}), str(f), fps)
            for f in files
            if f.suffix.lower() in by_ext
        ]
        if not jobs:
            raise PipelineError(f"no {self.reads} file matches {self.params.paths} (relative to {ctx.base_dir})")
        # ids of every readable file before reading: a file that fails keeps its would-be id
        return jobs, self.clip_ids([Path(j[2]) for j in jobs]), len(files)

    def _split(self, results: list[Any], ids: list[int]) -> tuple[list[Any], list[int], list[tuple[Any, ...]]]:
        good = [r for r in results if not isinstance(r, tuple)]
        good_ids = [c for c, r in zip(ids, results, strict=True) if not isinstance(r, tuple)]
        rejects = [(c, *r) for c, r in zip(ids, results, strict=True) if isinstance(r, tuple)]
        if rejects and self.params.on_error == "fail":
            raise ParseError(*rejects[0][1:])
        return good, good_ids, rejects

    def _read_all(
        self, ctx: StepContext, fps: float | None = None
    ) -> tuple[list[Any], list[int], list[tuple[Any, ...]], int, int]:
        """``(objects, their clip ids, rejects as (clip_id, path, line, message), files read,
        files skipped)``; raises on the first reject with ``on_error: fail``."""
        jobs, ids, n_files = self._jobs(ctx, fps)
        results = ctx.map(_read_file, jobs, desc=f"{ctx.step_id}: reading")
        good, good_ids, rejects = self._split(results, ids)
        return good, good_ids, rejects, len(jobs), n_files - len(jobs)

    @staticmethod
    def _rejects_table(rejects: list[tuple[Any, ...]]) -> pa.Table:
        return pa.Table.from_pylist(
            [{"clip_id": c, "path": p, "line": ln, "message": m} for c, p, ln, m in rejects], schema=schema.REJECTS
        )

    @staticmethod
    def _warnings_table(ids: list[int], paths: list[str], warnings: list[list[str]]) -> pa.Table:
        """What a reader repaired in a file it accepted (``metadata["warnings"]``: a header
        the data contradict...), one row per warning, the columns of ``rejects``."""
        rows = [
            {"clip_id": c, "path": p, "line": None, "message": w}
            for c, p, ws in zip(ids, paths, warnings, strict=True)
            for w in ws
        ]
        return pa.Table.from_pylist(rows, schema=schema.REJECTS)


class LoadMotions(_FileIngest):
    """Ingest motion files (mixed formats) into a motions dataset.

    Tables: ``data`` (one row per frame), ``clips``, ``skeletons``, ``rejects`` (file, line,
    message of every file that failed; the step goes on unless ``on_error: fail``),
    ``warnings`` (the same columns: what a reader repaired in a file it read).
    message of every file that failed; the step goes on unless ``on_error: fail``), and
    ``labels`` (clip or span -> label, :mod:`~mocapflow.framework.labels`) when ``labels``
    or ``label_pattern`` is given.
    Files with an extension no motion reader handles are counted as ``skipped_files``.
    """

    name = "load"
    reads = "motion"
    output_kind = "motions"
    version = "3"  # 3: rotations in their own table, per clip, smallest-three (schema.motion_rotations)

    class Params(_FileIngest.Params):
        fps: float | None = Field(default=None, gt=0, description="resample every clip to this rate (Hz)")

    params: Params

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        # the same tables as motions_to_tables(motions, ids), built clip by clip in the workers
        # and streamed to Parquet a batch of files at a time: the step never holds the library
        jobs, ids, n_files = self._jobs(ctx, self.params.fps)
        if len(set(ids)) != len(ids):
            raise DataError(f"need {len(ids)} distinct clip ids, got {len(set(ids))} distinct of {len(ids)}")
        data = ctx.table_writer("data", schema.motion_frames())
        rotations = ctx.table_writer("rotations", schema.motion_rotations())
        skeletons: dict[str, dict[str, Any]] = {}
        clips: list[dict[str, Any]] = []
        rejects: list[tuple[Any, ...]] = []
        warnings: tuple[list[int], list[str], list[list[str]]] = ([], [], [])
        batches = list(_batches([j[2] for j in jobs], max(1, ctx.executor.workers)))
        pending = 0  # frames in the rotations not yet written as a row group
        prev = _Previous.of(self, ctx)
        reused = 0
        for n, (a, b) in enumerate(batches):
            desc = f"{ctx.step_id}: reading" + (f" ({n + 1}/{len(batches)})" if len(batches) > 1 else "")
            kept = {i: prev.rows(jobs[i][2], ids[i]) for i in range(a, b)} if prev is not None else {}
            fresh = [i for i in range(a, b) if kept.get(i) is None]
            read = ctx.map(_read_motion_rows, [(*jobs[i], ids[i]) for i in fresh], desc=desc) if fresh else []
            results: list[Any] = [kept.get(i) for i in range(a, b)]
            for i, r in zip(fresh, read, strict=True):
                results[i - a] = r
            reused += (b - a) - len(fresh)
            got, got_ids, bad = self._split(results, ids[a:b])
            rejects += bad
            for g, cid in zip(got, got_ids, strict=True):
                key, name, n_joints, definition = g["skeleton"]  # first occurrence order, as skeletons_table
                skeletons.setdefault(
                    key, {"skeleton": key, "name": name, "n_joints": n_joints, "definition": definition}
                )
                data.write(g["frames"])
                rotations.write(g["rotations"])
                pending += g["clip"]["n_frames"]
                if pending >= ROTATION_GROUP_FRAMES:  # a clip slice decodes only the groups it needs
                    rotations.flush()
                    pending = 0
                clips.append(g["clip"])
                warnings[0].append(cid)
                warnings[1].append(g["clip"]["path"])
                warnings[2].append(g.get("warnings", []))
        reused_ids = [c["clip_id"] for c in clips if c.get("_reused")]
        for c in clips:
            c.pop("_reused", None)
        tables = {
            "data": data,
            "rotations": rotations,
            "clips": clips_table(clips),
            "skeletons": pa.Table.from_pylist(list(skeletons.values()), schema=schema.SKELETONS),
            "rejects": self._rejects_table(rejects),
            "warnings": self._warnings_table(*warnings),
            **self._labels(clips, ctx.base_dir),
        }
        summary = {
            "files": len(jobs),
            "clips": len(clips),
            "frames": int(sum(c["n_frames"] for c in clips)),
            "rejects": len(rejects),
            "warnings": tables["warnings"].num_rows,
            "skipped_files": n_files - len(jobs),
        }
        if prev is not None:
            # a library grown by a few takes: only the new or changed files were read; the
            # clips copied are listed (`reused`) for the steps downstream to copy theirs too
            summary["reused_clips"] = reused
            summary["read_files"] = len(jobs) - reused
            summary["reused_from"] = prev.ds.fingerprint
            tables["reused"] = pa.table({"clip_id": pa.array(reused_ids, pa.int32())})
        return StepOutput(tables, summary)


class _Previous:
    """The step's previous dataset in the workspace, when the same ingest (component version
    and every parameter but the file patterns and labels) wrote it: the rows of a file that
    did not change since (same path, clip id and SHA-1 of its bytes; for AMC, no ASF beside it
    newer than that dataset) are copied from it instead of read again."""

    IGNORED = ("paths", "exclude", "labels", "label_pattern")

    def __init__(self, ds: Dataset) -> None:
        from mocapflow.framework.clip_refs import row_groups

        self.ds = ds
        clips = ds.table("clips").to_pylist()
        n = np.array([c["n_frames"] for c in clips], np.int64)
        starts = np.concatenate([[0], np.cumsum(n)])
        self.by_path = {c["path"]: (i, c, int(starts[i]), int(starts[i + 1])) for i, c in enumerate(clips)}
        self.skeletons = {r["skeleton"]: r for r in ds.table("skeletons").to_pylist()}
        self.warnings: dict[int, list[str]] = {}
        if ds.has_table("warnings"):
            for w in ds.table("warnings").to_pylist():
                self.warnings.setdefault(int(w["clip_id"]), []).append(w["message"])
        self.groups = {t: row_groups(ds.path / f"{t}.parquet") for t in ("data", "rotations")}
        self.written = (ds.path / MANIFEST).stat().st_mtime

    @classmethod
    def of(cls, step: LoadMotions, ctx: StepContext) -> _Previous | None:
        try:
            ds = Dataset(ctx.workspace / ctx.step_id)
            same = (
                ds.producer == step.key()
                and str(ds.manifest.get("version")) == step.version
                and ds.has_table("rotations")
                and {k: v for k, v in ds.manifest.get("params", {}).items() if k not in cls.IGNORED}
                == {
                    k: v
                    for k, v in json.loads(json.dumps(step.get_params(), default=str)).items()
                    if k not in cls.IGNORED
                }
            )
            return cls(ds) if same else None
        except (PipelineError, OSError, ValueError, KeyError):  # none, or not readable: read every file
            return None

    def rows(self, path: str, clip_id: int) -> dict[str, Any] | None:
        """:func:`_read_motion_rows`'s result for ``path`` from the previous dataset, or None."""
        from mocapflow.framework.clip_refs import read_rows

        found = self.by_path.get(path)
        if found is None or found[1]["clip_id"] != clip_id:
            return None
        pos, clip, r0, r1 = found
        try:
            if path.lower().endswith(".amc") and any(
                a.stat().st_mtime >= self.written for a in Path(path).parent.glob("*.asf")
            ):
                return None  # its skeleton may have changed
            if hashlib.sha1(Path(path).read_bytes()).hexdigest() != clip["checksum"]:
                return None
        except OSError:
            return None
        sk = self.skeletons[clip["skeleton"]]
        ref = (str(self.ds.path), self.ds.fingerprint)
        return {
            "warnings": self.warnings.get(clip_id, []),
            "frames": read_rows(*ref, "data", self.groups["data"], r0, r1) or schema.motion_frames().empty_table(),
            "rotations": read_rows(*ref, "rotations", self.groups["rotations"], pos, pos + 1),
            "clip": {**clip, "_reused": True},
            "skeleton": (sk["skeleton"], sk["name"], sk["n_joints"], sk["definition"]),
        }


#: A batch of the ingest reads at most this many bytes of files (and this many files per
#: worker): what the client holds at once is one batch's rows, whatever the library's size.
BATCH_BYTES = 96 << 20
#: Frames per row group of the ``rotations`` table (one row per clip; a row group ends at the
#: first clip past this many frames): ~10 MB of a 31-joint skeleton's rotations.
ROTATION_GROUP_FRAMES = 65536
BATCH_FILES_PER_WORKER = 64


def _batches(paths: list[str], workers: int) -> list[tuple[int, int]]:
    """Consecutive ``[a, b)`` ranges of ``paths`` of at most :data:`BATCH_BYTES` of files
    (at least one file) and ``BATCH_FILES_PER_WORKER`` files per worker."""
    out, a, size = [], 0, 0
    for i, p in enumerate(paths):
        size += os.path.getsize(p) if os.path.isfile(p) else 0
        if size >= BATCH_BYTES or i + 1 - a >= BATCH_FILES_PER_WORKER * workers:
            out.append((a, i + 1))
            a, size = i + 1, 0
    if a < len(paths):
        out.append((a, len(paths)))
    return out


class LoadMarkers(_FileIngest):
    """Ingest marker files (C3D, TRC...) into a markers dataset.

    Tables: ``data`` (clip_id, frame, ``positions``: the clip's M*3 marker coordinates in
    metres as a list of float32, NaN in gaps), ``clips`` (clip_id, name, path, format, fps,
    n_frames, n_markers, labels, up_axis), ``rejects`` and ``warnings`` (what a reader
    repaired in a file it read: a ``NumFrames`` or a C3D header the data contradict).
    """

    name = "load_markers"
    reads = "markers"
    output_kind = "markers"

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        good, ids, rejects, n_files, _ = self._read_all(ctx)
        frames, clips = [], []
        for cid, mk in zip(ids, good, strict=True):
            t, m = mk.n_frames, mk.n_markers
            flat = mk.positions.astype(np.float32).reshape(-1)
            frames.append(
                pa.Table.from_arrays(
                    [
                        pa.array(np.full(t, cid, np.int32)),
                        pa.array(np.arange(t, dtype=np.int32)),
                        pa.ListArray.from_arrays(
                            pa.array(np.arange(0, t * m * 3 + 1, m * 3, dtype=np.int32)), pa.array(flat)
                        ),
                    ],
                    schema=schema.MARKER_FRAMES,
                )
            )
            clips.append(
                {
                    "clip_id": cid,
                    "name": mk.name,
                    "path": str(mk.metadata.get("path", "")),
                    "format": str(mk.metadata.get("format", "")),
                    "fps": mk.fps,
                    "n_frames": t,
                    "n_markers": m,
                    "labels": list(mk.labels),
                    "up_axis": str(mk.metadata.get("up_axis", "")),
                }
            )
        data = pa.concat_tables(frames) if frames else schema.MARKER_FRAMES.empty_table()
        tables = {
            "data": data,
            "clips": pa.Table.from_pylist(clips, schema=schema.MARKER_CLIPS),
            "rejects": self._rejects_table(rejects),
            "warnings": self._warnings_table(
                ids,
                [str(mk.metadata.get("path", "")) for mk in good],
                [mk.metadata.get("warnings") or [] for mk in good],
            ),
            **self._labels(clips, ctx.base_dir),
        }
        summary = {
            "files": n_files,
            "clips": len(good),
            "rejects": len(rejects),
            "warnings": tables["warnings"].num_rows,
        }
        return StepOutput(tables, summary)


class ExportMotions(Format):
    """Write every clip of a motions dataset to files (BVH or AMC/ASF) in the step folder."""

    name = "export"
    is_step = True
    inputs: ClassVar[Mapping[str, bool]] = {"motions": True}

    class Params(BaseParams):
        format: str = Field("bvh", description="registry name of a writer format (bvh, amc...)")

    params: Params

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        writer_cls = ctx.registries["formats"].get(self.params.format)
        if not writer_cls.can_write():
            raise PipelineError(f"format {self.params.format!r} has no writer")
        writer = writer_cls()
        ext = writer_cls.extensions[0] if writer_cls.extensions else f".{self.params.format}"
        db = inputs["motions"].motions()
        rows = []
        for cid, m in zip(
            db.clip_ids, ctx.progress(db.motions, total=db.n_clips, desc=f"{ctx.step_id}: writing"), strict=True
        ):
            out = ctx.out_dir / f"{int(cid):010d}_{m.name}{ext}"
            writer.write(m, out)
            rows.append({"clip_id": int(cid), "name": m.name, "file": out.name})
        table = pa.Table.from_pylist(rows, schema=schema.EXPORTS)
        return StepOutput({"data": table}, {"files": len(rows), "format": self.params.format})


__all__ = ["ExportMotions", "LoadMarkers", "LoadMotions"]
