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


class Catalog:
    """Read-only SQL over a workspace.

    Parameters
    ----------
    workspace : str or Path
        A directory written by ``mocapflow run``.
    """

    def __init__(self, workspace: str | Path) -> None:
        import duckdb

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
        import duckdb

        check_read_only(sql)
        try:
            rel = self._con.sql(sql, params=params)
            if rel is None:  # pragma: no cover - every allowed statement returns rows
                raise MocapflowError("SQL: the statement returned no result")
            return rel.to_arrow_table()
        except duckdb.PermissionException as exc:
            raise MocapflowError(
                f"SQL error: {exc} (the catalog reads only the datasets of {self.workspace})"
            ) from None
        except duckdb.Error as exc:
            raise MocapflowError(f"SQL error: {exc}") from None

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
