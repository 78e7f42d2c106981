"""A workspace's Parquet datasets as DuckDB views (the only module that imports duckdb).

Views: ``<step>`` for each dataset's main table, ``<step>_<table>`` for its other tables
(``motions_rejects``...), and the short names ``clips`` and ``rejects`` for the first
motions dataset (in step order) that has them. Step ids containing ``-`` also get a view
with ``_`` instead, so they can be written without quotes. Views are created through
DuckDB's relation API; queries take parameters (``?``), never string formatting.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import pyarrow as pa

from .datasets import read_datasets
from .errors import ConfigError, MocapflowError


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
        # an in-memory database: nothing is ever written into the workspace
        self._con = duckdb.connect(":memory:")
        self.views: dict[str, Path] = {}
        ordered = sorted(self.datasets.values(), key=lambda d: d.manifest.get("created", ""))
        for ds in ordered:
            for table in ds.table_names():
                view = ds.step if table == "data" else f"{ds.step}_{table}"
                path = ds.path / f"{table}.parquet"
                self._add_view(view, path)
                if table in ("clips", "rejects") and table not in self.views:
                    self._add_view(table, path)

    def _add_view(self, name: str, path: Path) -> None:
        rel = self._con.read_parquet(str(path))
        for alias in {name, name.replace("-", "_")}:
            if alias not in self.views:
                rel.create_view(alias, replace=True)
                self.views[alias] = path

    def query(self, sql: str, params: list[Any] | dict[str, Any] | None = None) -> pa.Table:
        """Run a query (``?`` or ``$name`` parameters) and return an Arrow table."""
        import duckdb

        try:
            return self._con.sql(sql, params=params).to_arrow_table()
        except duckdb.Error as exc:
            raise MocapflowError(f"SQL error: {exc}") from None

    def relation(self, view: str):
        """The DuckDB relation of one view (for the relational API)."""
        if view not in self.views:
            from .registry import did_you_mean

            raise ConfigError(f"no view {view!r}{did_you_mean(view, list(self.views))}")
        return self._con.table(view)

    def close(self) -> None:
        self._con.close()

    def __enter__(self) -> Catalog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def CSV_OPTIONS():  # noqa: N802 - a constant built lazily (pyarrow.csv is imported on demand)
    import pyarrow.csv as pacsv

    return pacsv.WriteOptions(quoting_style="needed", quoting_header="none")


def write_table(table: pa.Table, path: str | Path, fmt: str) -> None:
    """Write a query result as CSV or Parquet, atomically (temp file + rename)."""
    import os

    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    out = Path(path)
    tmp = out.with_name(f".{out.name}.tmp")
    if fmt == "csv":
        # nested columns (feature vectors, paths) are written as their text form
        cols = [c if not (pa.types.is_list(c.type) or pa.types.is_fixed_size_list(c.type) or pa.types.is_struct(c.type))
                else pa.array([None if v is None else str(v) for v in c.to_pylist()], pa.string()) for c in table.columns]
        pacsv.write_csv(pa.Table.from_arrays(cols, names=table.column_names), tmp, CSV_OPTIONS())
    elif fmt == "parquet":
        pq.write_table(table, tmp)
    else:
        raise ConfigError(f"unknown output format {fmt!r}: csv or parquet")
    os.replace(tmp, out)


def format_table(table: pa.Table, max_rows: int = 50, max_width: int = 40) -> str:
    """Plain-text rendering of an Arrow table for terminals."""
    names = table.column_names
    shown = table.slice(0, max_rows).to_pylist()

    def cell(v: Any) -> str:
        if isinstance(v, float):
            s = f"{v:.6g}"
        else:
            s = "NULL" if v is None else str(v)
        return s if len(s) <= max_width else s[: max_width - 1] + "…"

    rows = [[cell(r[n]) for n in names] for r in shown]
    widths = [max([len(n)] + [len(r[i]) for r in rows]) for i, n in enumerate(names)]
    line = "  ".join(n.ljust(w) for n, w in zip(names, widths))
    out = [line, "  ".join("-" * w for w in widths)]
    out += ["  ".join(c.ljust(w) for c, w in zip(r, widths)) for r in rows]
    more = table.num_rows - len(shown)
    out.append(f"({table.num_rows} row{'s' if table.num_rows != 1 else ''}{f', {more} not shown' if more > 0 else ''})")
    return "\n".join(out)
