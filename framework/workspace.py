"""The workspace: where a run's datasets live, and how a step's output is written.

Layout of a workspace folder (it may be a folder the user already had: the runner deletes or
replaces nothing it did not create)::

    <workspace>/<step>/                one finished dataset per step (see :mod:`.datasets`)
        data.parquet, <table>.parquet  the step's tables, provenance in their key-value metadata
        _manifest.json                 the provenance, written last: no manifest, no dataset
        ...                            files the component wrote (an index, a model, plots)
    <workspace>/.mocapflow/            the runner's own folder (carries MARKER)
        lock                           one run at a time (:class:`WorkspaceLock`)
        tmp/<step>-<id>/               a step being written
        trash/<step>-<id>/             the previous dataset while it is replaced

How a step's output is written (:meth:`Workspace.write_step`): the component writes files into
a temporary folder (``ctx.out_dir``) and returns its tables; the tables are written there
(:func:`write_table`), then the manifest, and the folder is renamed over ``<workspace>/<step>``
(:meth:`Workspace.commit`, atomic on one filesystem). A failed step leaves its previous dataset
as it was. Files written outside a step's folder go through :func:`atomic_path`; no command
but the runner writes inside one (:func:`.output_paths.refuse_dataset_path` checks every output option).

``.mocapflow/lock`` is an advisory ``flock`` (released by the kernel even on ``kill -9``) on a
file recording the holder; a holder recorded in a lock nobody holds was killed and is taken
over. Without ``flock`` the record decides (holder on this host and dead: taken over).
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import shutil
import socket
import time
import uuid
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import IO, Any

import pyarrow as pa

from .errors import ConfigError, LockError

log = logging.getLogger("mocapflow")

RUNNER_DIR = ".mocapflow"
MARKER = "CREATED-BY-MOCAPFLOW"
LOCK_FILE = "lock"
TMP_DIR = "tmp"
TRASH_DIR = "trash"
#: The provenance file of a dataset; a folder without it is not a finished dataset.
MANIFEST = "_manifest.json"
#: Rows per Parquet row group of the tables the runner writes: a worker reading a clip range
#: decodes only the groups that hold it (:class:`~.clip_refs.ClipSlice`), not the whole table.
ROW_GROUP_ROWS = 65536
_MARKER_TEXT = (
    "This folder was created by the mocapflow runner for its temporary files and its lock.\n"
    "mocapflow deletes what is inside tmp/ and trash/ here; it never deletes anything else.\n"
)


def runner_dir(workspace: str | Path) -> Path:
    """``<workspace>/.mocapflow``, created atomically with its marker if missing
    (:class:`ConfigError` if one exists without the marker: not ours to use or clean)."""
    d = Path(workspace) / RUNNER_DIR
    for _ in range(2):
        found = existing_runner_dir(workspace)
        if found is not None:
            return found
        staging = d.with_name(f"{RUNNER_DIR}-{uuid.uuid4().hex[:8]}")
        staging.mkdir(parents=True)
        (staging / MARKER).write_text(_MARKER_TEXT)
        try:
            os.rename(staging, d)  # atomic: the folder never exists without its marker
            return d
        except OSError:  # another run created it first: use theirs
            shutil.rmtree(staging, ignore_errors=True)
    raise ConfigError(f"cannot create {d}")  # pragma: no cover - only under a pathological race


def existing_runner_dir(workspace: str | Path) -> Path | None:
    """``<workspace>/.mocapflow`` if it exists (:class:`ConfigError` if it is not the runner's)."""
    d = Path(workspace) / RUNNER_DIR
    if not (d.exists() or d.is_symlink()):
        return None
    if d.is_symlink() or not d.is_dir() or not (d / MARKER).is_file():
        raise ConfigError(
            f"{d} exists but was not created by mocapflow (no {MARKER} inside); the runner keeps "
            "its temporary files there and will not touch it: move it away or choose another workspace"
        )
    return d


def remove_owned(workspace: str | Path, *names: str) -> None:
    """Delete ``names`` (e.g. ``tmp``, ``trash``) inside the runner's own marked folder only."""
    d = existing_runner_dir(workspace)
    if d is not None:
        for name in names:
            shutil.rmtree(d / name, ignore_errors=True)


def _proc_start(pid: int) -> str | None:
    """Start time of a process in clock ticks since boot (Linux), to tell pid reuse apart."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        return stat.rpartition(")")[2].split()[19]
    except (OSError, IndexError):
        return None


def holder_alive(holder: dict[str, Any]) -> bool:
    """Whether the process recorded in a lock may still run (``True`` when it cannot be told)."""
    pid = holder.get("pid")
    if holder.get("host") != socket.gethostname() or not isinstance(pid, int):
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    start = holder.get("proc_start")
    return start is None or _proc_start(pid) in (None, start)


def describe_holder(holder: dict[str, Any]) -> str:
    if not holder:
        return "a process that left no record"
    pipeline = f", pipeline {holder['pipeline']!r}" if holder.get("pipeline") else ""
    return f"pid {holder.get('pid')} on host {holder.get('host')}, started {holder.get('started')}{pipeline}"


class WorkspaceLock:
    """Exclusive use of a workspace by one run (a context manager): waits up to ``wait``
    seconds (``inf``: forever) for another run, then raises :class:`LockError` naming it;
    ``pipeline`` is recorded for that message, ``echo`` gets the "waiting" line."""

    def __init__(
        self,
        workspace: str | Path,
        wait: float = 0.0,
        pipeline: str = "",
        echo: Callable[[str], None] | None = None,
        poll: float = 0.2,
    ) -> None:
        self.workspace = Path(workspace)
        self.wait = float(wait)
        self.pipeline = pipeline
        self.echo = echo or (lambda msg: None)
        self.poll = poll
        self._fd: int | None = None
        self.path: Path | None = None

    def _read(self, fd: int) -> dict[str, Any]:
        try:
            os.lseek(fd, 0, os.SEEK_SET)
            raw = b""
            while chunk := os.read(fd, 65536):
                raw += chunk
            return json.loads(raw) if raw.strip() else {}
        except (OSError, ValueError):
            return {"pid": None, "host": "?", "started": "?"}

    def _write(self, fd: int) -> None:
        me = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "proc_start": _proc_start(os.getpid()),
            "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "pipeline": self.pipeline,
        }
        os.ftruncate(fd, 0)
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, json.dumps(me).encode())
        os.fsync(fd)

    def _try_flock(self, fd: int) -> bool | None:
        """True: locked; False: held by another; None: this filesystem has no flock."""
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            return False
        except OSError as exc:
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                return False
            if exc.errno in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):
                return None
            raise

    def acquire(self) -> WorkspaceLock:
        self.workspace.mkdir(parents=True, exist_ok=True)
        self.path = runner_dir(self.workspace) / LOCK_FILE
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        deadline = time.monotonic() + self.wait
        waiting = False
        try:
            while True:
                got = self._try_flock(fd)
                holder = self._read(fd)
                if got is None:  # no flock here: the record decides
                    got = not holder or not holder_alive(holder)
                if got:
                    break
                if time.monotonic() >= deadline:
                    hint = (
                        "wait for it to finish, or pass a longer --wait SECONDS"
                        if self.wait
                        else "wait for it to finish, or pass --wait SECONDS to wait for it"
                    )
                    raise LockError(
                        f"workspace {self.workspace} is in use by another run ({describe_holder(holder)}); {hint}"
                    )
                if not waiting:
                    self.echo(
                        f"  workspace {self.workspace} is in use by {describe_holder(holder)}; waiting "
                        f"{'as long as it takes' if self.wait == float('inf') else f'up to {self.wait:g} s'}..."
                    )
                    waiting = True
                time.sleep(self.poll)
            if holder:
                state = "is no longer running" if not holder_alive(holder) else "no longer holds it"
                log.warning(
                    "workspace %s: taking over the lock of a run that did not finish (%s, which %s); "
                    "its unfinished outputs are discarded",
                    self.workspace,
                    describe_holder(holder),
                    state,
                )
            self._write(fd)
        except BaseException:
            os.close(fd)
            raise
        self._fd = fd
        return self

    def release(self) -> None:
        """Clear the record (so the next run sees a clean release), then unlock."""
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        try:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)
        finally:
            os.close(fd)  # closing the last descriptor releases the flock

    def __enter__(self) -> WorkspaceLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


class Workspace:
    """A workspace folder as the runner uses it; deletes only inside the runner's marked
    folder or a step folder holding a :data:`MANIFEST`."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    def lock(self, wait: float = 0.0, pipeline: str = "", echo: Callable[[str], None] | None = None) -> WorkspaceLock:
        """The lock a run holds from start to end (a context manager)."""
        return WorkspaceLock(self.path, wait, pipeline, echo)

    def check_outputs(self, step_ids: list[str]) -> None:
        """Refuse, before anything runs, to replace a folder the runner did not write, or to
        write a workspace that lies inside another workspace's dataset or runner folder
        (through links too)."""
        real = self.path.absolute().resolve()
        if real.exists() and not real.is_dir():
            raise ConfigError(f"workspace {self.path} exists and is not a folder: choose another workspace")
        _refuse_name(real, self.path, "workspace")
        for step_id in step_ids:
            out = self.path / step_id
            if (out.exists() or out.is_symlink()) and (
                out.is_symlink() or not out.is_dir() or not (out / MANIFEST).is_file()
            ):
                raise ConfigError(
                    f"{out} exists and is not a mocapflow dataset (no {MANIFEST}); step {step_id!r} "
                    "would replace it: move it away, rename the step, or choose another workspace"
                )

    def clean_leftovers(self) -> None:
        """Remove half-written outputs of an interrupted run (call while holding the lock)."""
        remove_owned(self.path, TMP_DIR, TRASH_DIR)

    def fingerprint(self, step_id: str) -> str | None:
        """The fingerprint recorded by the finished dataset of ``step_id`` (None: none, or unreadable)."""
        try:
            value = json.loads((self.path / step_id / MANIFEST).read_text()).get("fingerprint")
        except (OSError, ValueError):
            return None
        return value if isinstance(value, str) else None

    def temp_dir(self, step_id: str) -> Path:
        """A new empty folder for one step's output, inside the runner's folder."""
        tmp = runner_dir(self.path) / TMP_DIR / f"{step_id}-{uuid.uuid4().hex[:8]}"
        tmp.mkdir(parents=True)
        return tmp

    def write_step(
        self, tmp: Path, step_id: str, tables: Mapping[str, pa.Table | TableWriter], provenance: dict[str, Any]
    ) -> None:
        """Write a step's tables and manifest into ``tmp`` and commit it as ``<workspace>/<step_id>``.

        A :class:`TableWriter` value is a table the step already streamed into ``tmp``: it
        gets the provenance and its footer here. A write that fails (a full disk) raises
        :class:`~.errors.PipelineError` naming the table; the runner then removes ``tmp``."""
        try:
            for name, table in tables.items():
                if isinstance(table, TableWriter):
                    table.close(provenance)
                else:
                    write_table(table, tmp / f"{name}.parquet", provenance)
        except OSError as exc:
            raise write_error(exc) from exc
        manifest = {**provenance, "tables": {name: t.num_rows for name, t in tables.items()}}
        # the manifest is written last: a directory without it is never a dataset
        (tmp / MANIFEST).write_text(json.dumps(manifest, indent=2, sort_keys=True, default=str))
        self.commit(tmp, step_id)

    def commit(self, tmp: Path, step_id: str) -> None:
        """Swap the finished temporary folder in with renames (atomic on one filesystem)."""
        final = self.path / step_id
        if final.exists():
            trash = runner_dir(self.path) / TRASH_DIR / f"{final.name}-{uuid.uuid4().hex[:8]}"
            trash.parent.mkdir(parents=True, exist_ok=True)
            os.replace(final, trash)
            os.replace(tmp, final)
            shutil.rmtree(trash, ignore_errors=True)
        else:
            os.replace(tmp, final)

    def dataset_dirs(self) -> list[Path]:
        """Folders of the finished datasets, sorted by step id."""
        if not self.path.is_dir():
            return []
        return [
            d
            for d in sorted(self.path.iterdir())
            if d.is_dir() and not d.name.startswith(".") and (d / MANIFEST).is_file()
        ]


def write_table(table: pa.Table, path: Path, provenance: Mapping[str, Any]) -> None:
    """One table of a step as Parquet, the provenance in its key-value metadata (``mocapflow``)."""
    import pyarrow.parquet as pq

    meta = dict(table.schema.metadata or {})
    meta[b"mocapflow"] = json.dumps(provenance, sort_keys=True, default=str).encode()
    pq.write_table(
        table.replace_schema_metadata(meta), path, row_group_size=ROW_GROUP_ROWS, **parquet_options(table.schema)
    )


def write_error(exc: OSError) -> Exception:
    """A failed write of a step's output (a full disk, a quota) as one clear error."""
    from .errors import PipelineError

    what = exc.strerror or str(exc)
    err = PipelineError(
        f"cannot write its output ({what}{f': {exc.filename}' if exc.filename else ''}); nothing of the "
        "step was kept in the workspace: free space (or choose another workspace) and run again"
    )
    err.__cause__ = exc
    return err


def parquet_options(schema: pa.Schema) -> dict[str, Any]:
    """How the runner writes a table: zstd; dictionaries only for strings and statistics only
    for flat columns (DuckDB prunes row groups on clip_id/frame; both cost seconds on large
    nested float columns); byte-stream-split for float columns (the bytes of like magnitude
    together: 10-25 % smaller time series under zstd)."""
    flat = [f.name for f in schema if not pa.types.is_nested(f.type)]
    strings = [f.name for f in schema if pa.types.is_string(f.type) or pa.types.is_large_string(f.type)]
    floats = [
        f.name
        for f in schema
        if pa.types.is_floating(f.type)
        or (
            (pa.types.is_list(f.type) or pa.types.is_fixed_size_list(f.type) or pa.types.is_large_list(f.type))
            and pa.types.is_floating(f.type.value_type)
        )
    ]
    return {
        "compression": "zstd",
        "use_dictionary": strings or False,
        "write_statistics": flat or False,
        "use_byte_stream_split": floats or False,
    }


class TableWriter:
    """A table a step writes in pieces (bounded memory): ``write(table)`` any number of
    times, rows buffered up to :data:`ROW_GROUP_ROWS` and written as Parquet row groups
    into the step's temporary folder (``ctx.table_writer``). Return it in
    ``StepOutput.tables``; the runner closes it with the provenance (:meth:`close`)."""

    def __init__(self, path: Path, schema: pa.Schema, row_group_rows: int | None = None) -> None:
        self.path = Path(path)
        self.schema = schema
        self.row_group_rows = int(ROW_GROUP_ROWS if row_group_rows is None else row_group_rows)
        self.num_rows = 0
        self._pending: list[pa.Table] = []
        self._pending_rows = 0
        self._writer: Any = None
        self._closed = False

    def _open(self) -> Any:
        import pyarrow.parquet as pq

        if self._writer is None:
            self._writer = pq.ParquetWriter(self.path, self.schema, **parquet_options(self.schema))
        return self._writer

    def write(self, table: pa.Table) -> None:
        """Append rows (the writer's schema; columns cast where only the metadata differs)."""
        if self._closed:
            raise ValueError(f"{self.path.name}: written after close")
        if table.num_rows == 0:
            return
        if table.schema != self.schema:
            table = table.cast(self.schema)
        self._pending.append(table)
        self._pending_rows += table.num_rows
        self.num_rows += table.num_rows
        if self._pending_rows >= self.row_group_rows:
            self._flush(final=False)

    def _flush(self, final: bool) -> None:
        if not self._pending:
            return
        data = pa.concat_tables(self._pending)
        cut = data.num_rows if final else data.num_rows - data.num_rows % self.row_group_rows
        if cut:
            self._open().write_table(data.slice(0, cut), row_group_size=self.row_group_rows)
        rest = data.slice(cut)
        self._pending = [rest] if rest.num_rows else []
        self._pending_rows = rest.num_rows

    def flush(self) -> None:
        """Write what is buffered as a row group now (the end of a batch)."""
        self._flush(final=True)

    def close(self, provenance: Mapping[str, Any] | None = None) -> None:
        """Write what is buffered, the provenance (key-value metadata ``mocapflow``) and the footer."""
        if self._closed:
            return
        self._flush(final=True)
        writer = self._open()  # an empty table still gets its file
        if provenance is not None:
            writer.add_key_value_metadata({"mocapflow": json.dumps(provenance, sort_keys=True, default=str)})
        self._closed = True
        writer.close()


def _refuse_name(p: Path, path: str | Path, option: str) -> None:
    """The name rule: ``p`` (absolute, links resolved or not) lies in a dataset or runner folder."""
    for cand in (p, *p.parents):
        if (cand / MANIFEST).is_file():
            raise ConfigError(
                f"{option} {path}: {cand} is a dataset of a mocapflow workspace; only `mocapflow run` "
                "writes there: choose a path outside the step folders"
            )
        if cand.name == RUNNER_DIR and (cand / MARKER).is_file():
            raise ConfigError(f"{option} {path}: {cand} is the mocapflow runner's own folder: choose another path")


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix), renamed over ``path`` when the
    block succeeds, removed otherwise: never half a file, the old one kept on failure."""
    final = Path(path)
    tmp = final.with_name(f".{final.stem}.{uuid.uuid4().hex[:8]}.tmp{final.suffix}")
    try:
        yield tmp
        os.replace(tmp, final)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def csv_options() -> Any:
    """How tables are written as CSV (``mocapflow sql --format csv``, :func:`export_table`)."""
    import pyarrow.csv as pacsv

    return pacsv.WriteOptions(quoting_style="needed", quoting_header="none")


def _json_value(v: Any) -> Any:
    """A value of a table row as JSON can hold it: NaN and infinities become null, bytes
    hex, dates and times ISO 8601, decimals floats; lists and dicts element by element."""
    import datetime
    import decimal
    import math

    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, (list, tuple)):
        return [_json_value(x) for x in v]
    if isinstance(v, dict):
        return {str(k): _json_value(x) for k, x in v.items()}
    if isinstance(v, (bytes, bytearray, memoryview)):
        return bytes(v).hex()
    if isinstance(v, (datetime.date, datetime.time)):
        return v.isoformat()
    if isinstance(v, datetime.timedelta):
        return v.total_seconds()
    if isinstance(v, decimal.Decimal):
        return float(v)
    return v


def _is_nested(t: pa.DataType) -> bool:
    return bool(
        pa.types.is_list(t)
        or pa.types.is_large_list(t)
        or pa.types.is_fixed_size_list(t)
        or pa.types.is_struct(t)
        or pa.types.is_map(t)
        or pa.types.is_union(t)
    )


def _is_binary(t: pa.DataType) -> bool:
    return bool(pa.types.is_binary(t) or pa.types.is_large_binary(t) or pa.types.is_fixed_size_binary(t))


def flat_table(table: pa.Table) -> pa.Table:
    """``table`` with every nested column (list, fixed-size list, struct, map: feature
    vectors, paths, label lists) as JSON text and every binary column (packed rotations) as
    hex text, so a CSV writer takes it; other columns unchanged. A map becomes a JSON list
    of ``[key, value]`` pairs, as Arrow gives it."""
    if not any(_is_nested(f.type) or _is_binary(f.type) for f in table.schema):
        return table
    cols = []
    for c in table.columns:
        if _is_nested(c.type):
            vals = [None if v is None else json.dumps(_json_value(v), separators=(",", ":")) for v in c.to_pylist()]
            cols.append(pa.array(vals, pa.string()))
        elif _is_binary(c.type):
            cols.append(pa.array([None if v is None else bytes(v).hex() for v in c.to_pylist()], pa.string()))
        else:
            cols.append(c)
    return pa.Table.from_arrays(cols, names=table.column_names)


def write_json(table: pa.Table, out: IO[str]) -> None:
    """``table`` as a JSON array of row objects (column -> value; nested columns as JSON
    arrays and objects, NaN as null), one row a line."""
    out.write("[")
    for i, row in enumerate(table.to_pylist()):
        out.write(("\n" if i == 0 else ",\n") + json.dumps(_json_value(row), separators=(",", ":")))
    out.write("\n]\n" if table.num_rows else "]\n")


def export_table(table: pa.Table, path: str | Path, fmt: str) -> None:
    """Write a table (a query result) as CSV, JSON or Parquet, atomically; nested columns
    (feature vectors, paths) go to CSV as JSON text (:func:`flat_table`)."""
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    if fmt not in ("csv", "json", "parquet"):
        raise ConfigError(f"unknown output format {fmt!r}: csv, json or parquet")
    with atomic_path(path) as tmp:
        if fmt == "parquet":
            pq.write_table(table, tmp)
            return
        if fmt == "json":
            with open(tmp, "w", encoding="utf-8") as f:
                write_json(table, f)
            return
        pacsv.write_csv(flat_table(table), tmp, csv_options())
