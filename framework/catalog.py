"""A workspace's Parquet datasets as DuckDB views (the only module that imports duckdb).

Views: ``<step>`` (main table), ``<step>_<table>``, ``clips`` (the clips of every ingest,
one row per clip id), ``rejects``/``labels`` of the first dataset that has them; ``-`` in step ids also as ``_``. Read-only for real: only query statements
run, and DuckDB is opened with external access limited to the datasets' directories and
its configuration locked (no other file read, no extension loaded).
"""

from __future__ import annotations

import re
import shutil
import tempfile
from pathlib import Path
from typing import Any

import pyarrow as pa

from .datasets import read_datasets
from .errors import ConfigError, MocapflowError

_EXPLAIN = re.compile(r"^\s*EXPLAIN(\s+ANALYZE)?\s+", re.IGNORECASE)


def check_read_only(sql: str) -> None:
    """Raise :class:`ConfigError` unless every statement of ``sql`` only reads (DuckDB's
    parser decides; ``EXPLAIN`` only before a query: ``EXPLAIN ANALYZE COPY`` copies)."""
    import duckdb

    try:
        statements = duckdb.extract_statements(sql)
    except duckdb.Error as exc:
        raise MocapflowError(f"SQL error: {exc}") from None
    if not statements:
        raise ConfigError("SQL: no statement given")
    for st in statements:
        kind = st.type.name
        if kind == "EXPLAIN":
            inner = _EXPLAIN.sub("", st.query, count=1)
            if inner != st.query:
                check_read_only(inner)
                continue
        if kind != "SELECT":
            text = " ".join(st.query.split())
            raise ConfigError(
                f"the workspace catalog is read-only: {kind} statements are not allowed "
                f"({text[:60]}{'...' if len(text) > 60 else ''}); "
                "only queries (SELECT, WITH, FROM, VALUES, DESCRIBE, SHOW, SUMMARIZE, EXPLAIN)"
            )


_SIZE = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([KMGT]?)i?B?\s*$", re.IGNORECASE)


def parse_size(text: str) -> int:
    """Bytes of a size such as ``4GB``, ``512MB``, ``1.5GiB`` (1024-based), ``1000000``."""
    m = _SIZE.match(str(text))
    if not m or float(m.group(1)) <= 0:
        raise ConfigError(f"expected a memory size such as 4GB or 512MB, got {text!r}")
    return int(float(m.group(1)) * 1024 ** " KMGT".index(m.group(2).upper() or " "))


class Catalog:
    """Read-only SQL over a workspace.

    Parameters
    ----------
    workspace : str or Path
        A directory written by ``mocapflow run``.
    timeout : float, optional
        Seconds a query may run before it is interrupted (:class:`MocapflowError`); None: no limit.
    memory_limit : str, optional
        DuckDB's ``memory_limit`` (``"4GB"``) and the most a query's result may take; None:
        DuckDB's default (80 % of the RAM) and no bound on the result.
    """

    def __init__(self, workspace: str | Path, timeout: float | None = None, memory_limit: str | None = None) -> None:
        import duckdb

        self.timeout = timeout
        self.memory_bytes = parse_size(memory_limit) if memory_limit is not None else None
        self.workspace = Path(workspace)
        if not self.workspace.is_dir():
            raise ConfigError(f"workspace {self.workspace} does not exist (run a pipeline first)")
        self.datasets = read_datasets(self.workspace)
        if not self.datasets:
            raise ConfigError(f"workspace {self.workspace} holds no finished dataset")
        # an in-memory database that can read the datasets' directories and nothing else;
        # its spill directory is private (DuckDB allows it implicitly) and removed on close
        self._spill = tempfile.mkdtemp(prefix="mocapflow-duckdb-")
        self.views: dict[str, Path] = {}
        try:
            self._con = duckdb.connect(
                ":memory:",
                config={
                    "autoinstall_known_extensions": False,
                    "autoload_known_extensions": False,
                    "allow_community_extensions": False,
                    "temp_directory": self._spill,
                },
            )
            allowed = sorted({f"{ds.path.resolve()}/" for ds in self.datasets.values()})
            try:
                self._con.execute("SET allowed_directories = ?", [allowed])
            except duckdb.Error as exc:  # never fall back to a catalog that can read everything
                raise ConfigError(
                    f"the workspace catalog needs duckdb >= 1.2 (allowed_directories), found "
                    f"{duckdb.__version__}: pip install -U duckdb ({exc})"
                ) from None
            if self.memory_bytes is not None:
                self._con.execute(f"SET memory_limit = '{self.memory_bytes // 1024}KiB'")
            self._con.execute("SET enable_external_access = false")
            self._con.execute("SET lock_configuration = true")
            ordered = sorted(self.datasets.values(), key=lambda d: d.manifest.get("created", ""))
            clips: list[Path] = []
            for ds in ordered:
                for table in ds.table_names():
                    view = ds.step if table == "data" else f"{ds.step}_{table}"
                    path = ds.path / f"{table}.parquet"
                    self._add_view(view, path)
                    if table == "clips":
                        clips.append(path)
                    if table in ("rejects", "labels") and table not in self.views:
                        self._add_view(table, path)
            if clips:
                self._add_clips_view(clips)
        except BaseException:
            shutil.rmtree(self._spill, ignore_errors=True)
            raise

    def _add_clips_view(self, paths: list[Path]) -> None:
        """``clips``: every ingest's clips, one row per clip id (the first dataset's row),
        so a step's ``clip_id`` joins whichever ingest it came from (ids are per take)."""
        if len(paths) == 1:
            self._add_view("clips", paths[0])
            return
        parts = []
        for i, path in enumerate(paths):
            quoted = str(path.resolve()).replace("'", "''")
            parts.append(f"SELECT *, {i} AS _ingest FROM read_parquet('{quoted}', file_row_number = true)")
        self._con.sql(
            "SELECT * EXCLUDE (_ingest, file_row_number) FROM ("
            + " UNION ALL BY NAME ".join(parts)
            + ") QUALIFY row_number() OVER (PARTITION BY clip_id ORDER BY _ingest, file_row_number) = 1"
            " ORDER BY _ingest, file_row_number"
        ).create_view("clips", replace=True)
        self.views["clips"] = paths[0]

    def _add_view(self, name: str, path: Path) -> None:
        rel = self._con.read_parquet(str(path.resolve()))
        for alias in {name, name.replace("-", "_")}:
            if alias not in self.views:
                rel.create_view(alias, replace=True)
                self.views[alias] = path

    def query(self, sql: str, params: list[Any] | dict[str, Any] | None = None) -> pa.Table:
        """Run a query (``?`` or ``$name`` parameters) and return an Arrow table.

        Raises :class:`ConfigError` for statements that would write or load anything
        (see the module doc) and :class:`MocapflowError` for SQL errors, including reads
        of files outside the workspace's datasets.
        """
        import threading

        import duckdb

        check_read_only(sql)
        timer = None
        if self.timeout is not None:
            timer = threading.Timer(self.timeout, self._con.interrupt)
            timer.daemon = True
            timer.start()
        try:
            rel = self._con.sql(sql, params=params)
            if rel is None:  # pragma: no cover - every allowed statement returns rows
                raise MocapflowError("SQL: the statement returned no result")
            return self._collect(rel)
        except duckdb.InterruptException:
            raise MocapflowError(
                f"SQL: the query ran longer than {self.timeout:g} s and was stopped (--timeout SECONDS, 0: no limit)"
            ) from None
        except duckdb.OutOfMemoryException as exc:
            raise MocapflowError(f"SQL: the query needs more memory than its limit (--memory-limit): {exc}") from None
        except duckdb.PermissionException as exc:
            raise MocapflowError(
                f"SQL error: {exc} (the catalog reads only the datasets of {self.workspace})"
            ) from None
        except duckdb.Error as exc:
            raise MocapflowError(f"SQL error: {exc}") from None
        finally:
            if timer is not None:
                timer.cancel()

    def _collect(self, rel: Any) -> pa.Table:
        """The result as Arrow, read in batches: with a memory limit, a result larger than
        it is refused as it grows (DuckDB's own limit does not cover the result)."""
        if self.memory_bytes is None:
            return rel.to_arrow_table()
        to_reader = getattr(rel, "to_arrow_reader", None) or rel.fetch_record_batch  # duckdb >= 1.4 / older
        reader = to_reader(65536)
        batches, size = [], 0
        for batch in reader:
            size += batch.nbytes
            if size > self.memory_bytes:
                raise MocapflowError(
                    f"SQL: the result is larger than the memory limit ({self.memory_bytes / 2**20:,.0f} MiB; "
                    "--memory-limit): select fewer rows or columns, or aggregate"
                )
            batches.append(batch)
        return pa.Table.from_batches(batches, schema=reader.schema)

    def relation(self, view: str) -> Any:
        """The DuckDB relation of one view (for the relational API)."""
        if view not in self.views:
            from .registry import did_you_mean

            raise ConfigError(f"no view {view!r}{did_you_mean(view, list(self.views))}")
        return self._con.table(view)

    def close(self) -> None:
        self._con.close()
        shutil.rmtree(self._spill, ignore_errors=True)

    def __enter__(self) -> Catalog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def format_table(table: pa.Table, max_rows: int = 50, max_width: int = 40) -> str:
    """Plain-text rendering of an Arrow table for terminals."""
    names = table.column_names
    shown = table.slice(0, max_rows).to_pylist()

    def cell(v: Any) -> str:
        s = f"{v:.6g}" if isinstance(v, float) else "NULL" if v is None else str(v)
        return s if len(s) <= max_width else s[: max_width - 1] + "…"

    rows = [[cell(r[n]) for n in names] for r in shown]
    widths = [max([len(n)] + [len(r[i]) for r in rows]) for i, n in enumerate(names)]
    line = "  ".join(n.ljust(w) for n, w in zip(names, widths, strict=True))
    out = [line, "  ".join("-" * w for w in widths)]
    out += ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
    more = table.num_rows - len(shown)
    out.append(f"({table.num_rows} row{'s' if table.num_rows != 1 else ''}{f', {more} not shown' if more > 0 else ''})")
    return "\n".join(out)


#: Address space a query process may take beyond what it holds once the catalog is open and
#: beyond ``--memory-limit``: room for DuckDB's threads, Arrow's buffers and the result file.
QUERY_HEADROOM_BYTES = 256 * 2**20
#: Seconds the query process is given past ``--timeout`` to stop on its own (DuckDB's
#: interrupt) before it is killed.
QUERY_KILL_GRACE_S = 2.0


def _vm_size() -> int:
    """This process's address space in bytes (``VmSize``; 0 where /proc is missing)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def _query_child(
    conn: Any, workspace: str, sql: str, params: Any, timeout: float | None, memory: str | None, out: str
) -> None:
    """The query process: open the catalog, cap its own address space, run, write the result
    as an Arrow IPC file; report ``(kind, message)`` on ``conn``."""
    import resource

    try:
        with Catalog(workspace, timeout=timeout, memory_limit=memory) as cat:
            if cat.memory_bytes is not None:
                cap = _vm_size() + cat.memory_bytes + QUERY_HEADROOM_BYTES
                _, hard = resource.getrlimit(resource.RLIMIT_AS)
                if hard == resource.RLIM_INFINITY or cap < hard:
                    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
            table = cat.query(sql, params)
            with pa.OSFile(out, "wb") as sink, pa.ipc.new_file(sink, table.schema) as writer:
                writer.write_table(table)
        conn.send(("ok", ""))
    except MemoryError:
        conn.send(("memory", ""))
    except ConfigError as exc:
        conn.send(("config", str(exc)))
    except MocapflowError as exc:
        conn.send(("error", str(exc)))
    except BaseException as exc:  # reported to the parent, which names the limit
        text = f"{type(exc).__name__}: {exc}"
        conn.send(("memory" if "bad_alloc" in text or "memory" in text.lower() else "internal", text))


def limited_query(
    workspace: str | Path,
    sql: str,
    params: list[Any] | dict[str, Any] | None = None,
    timeout: float | None = None,
    memory_limit: str | None = None,
) -> pa.Table:
    """:meth:`Catalog.query` run in a child process whose limits hold for any query: its
    address space is capped (``RLIMIT_AS``: what it holds with the catalog open, plus
    ``memory_limit``, plus :data:`QUERY_HEADROOM_BYTES`) and it is killed
    :data:`QUERY_KILL_GRACE_S` after ``timeout`` if DuckDB's own interrupt has not stopped it.
    The error says which limit ended the query. The result comes back as an Arrow file
    (memory-mapped, removed at once)."""
    import multiprocessing as mp
    import signal
    import time

    memory_bytes = parse_size(memory_limit) if memory_limit is not None else None
    check_read_only(sql)  # refused here, before a process is started
    tmp = tempfile.mkdtemp(prefix="mocapflow-sql-")
    out = str(Path(tmp) / "result.arrow")
    ctx = mp.get_context("fork")
    recv, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(
        target=_query_child, args=(send, str(workspace), sql, params, timeout, memory_limit, out), daemon=True
    )
    try:
        proc.start()
        send.close()
        deadline = None if timeout is None else time.monotonic() + timeout + QUERY_KILL_GRACE_S
        ready = False
        while not ready:  # in slices: a poll of a very long timeout overflows
            left = 60.0 if deadline is None else min(60.0, deadline - time.monotonic())
            if left <= 0:
                break
            ready = recv.poll(left)
        msg = None
        if ready:
            try:
                msg = recv.recv()
            except EOFError:
                msg = None
        killed = False
        if msg is None and proc.is_alive():
            proc.kill()
            killed = not ready  # nothing came back before the deadline
        proc.join()
        if msg is None:
            if killed:
                raise MocapflowError(
                    f"SQL: the query ran longer than {timeout:g} s and was killed (--timeout SECONDS, 0: no limit)"
                )
            code = proc.exitcode or 0
            how = f"signal {signal.Signals(-code).name}" if code < 0 else f"exit status {code}"
            if memory_bytes is not None:
                raise MocapflowError(
                    f"SQL: the query process ended ({how}) at its memory limit "
                    f"({memory_bytes / 2**20:,.0f} MiB; --memory-limit SIZE)"
                )
            raise MocapflowError(f"SQL: the query process ended unexpectedly ({how})")
        kind, text = msg
        if kind == "ok":
            with pa.memory_map(out) as src:
                return pa.ipc.open_file(src).read_all()
        if kind == "memory":
            limit = f"{memory_bytes / 2**20:,.0f} MiB" if memory_bytes is not None else "none set"
            raise MocapflowError(
                f"SQL: the query needs more memory than its limit ({limit}; --memory-limit SIZE)"
                + (f": {text}" if text else "")
            )
        if kind == "config":
            raise ConfigError(text)
        if kind == "error":
            raise MocapflowError(text)
        raise MocapflowError(f"SQL: the query process failed: {text}")
    finally:
        if proc.is_alive():
            proc.kill()
            proc.join()
        recv.close()
        shutil.rmtree(tmp, ignore_errors=True)
