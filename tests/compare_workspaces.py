"""Compare every Parquet table of two workspaces of the same pipeline.

    python tests/compare_workspaces.py OLD_WORKSPACE NEW_WORKSPACE

(how a change is checked to leave shipped pipelines' tables identical; tests/framework/test_query_path.py
keeps it working)

Clip ids are mapped from old to new through the ``clips`` tables (same ``path``), so that a
change of id values alone is reported once ("clip ids remapped"), not as a difference in
every table. Then per table: columns added/removed, type changes, row counts, and, for the
columns both have, the rows (nested lists flattened; floats with ``--rtol``/``--atol``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

ID_COLUMNS = ("clip_id", "query_clip_id")


def clip_map(old: Path, new: Path) -> dict[int, int]:
    """old clip id -> new clip id, through the paths of every ``clips``/``rejects`` table."""
    out: dict[int, int] = {}
    for name in ("clips.parquet", "rejects.parquet"):
        for d in sorted(p for p in old.iterdir() if (p / name).is_file() and (new / p.name / name).is_file()):
            a, b = pq.read_table(d / name), pq.read_table(new / d.name / name)
            if "clip_id" not in a.column_names or "clip_id" not in b.column_names:
                continue
            by_path = dict(zip(b["path"].to_pylist(), b["clip_id"].to_pylist(), strict=True))
            for p, c in zip(a["path"].to_pylist(), a["clip_id"].to_pylist(), strict=True):
                if p in by_path:
                    out.setdefault(int(c), int(by_path[p]))
    return out


def _values(col: pa.ChunkedArray) -> np.ndarray | list:
    t = col.type
    while pa.types.is_list(t) or pa.types.is_fixed_size_list(t) or pa.types.is_large_list(t):
        col = pa.chunked_array([c.flatten() for c in col.chunks], type=t.value_type)
        t = t.value_type
    if pa.types.is_floating(t) or pa.types.is_integer(t) or pa.types.is_boolean(t):
        return col.to_numpy()
    return col.to_pylist()


def compare_table(a: pa.Table, b: pa.Table, ids: dict[int, int], rtol: float, atol: float) -> list[str]:
    notes = []
    an, bn = set(a.column_names), set(b.column_names)
    if an - bn:
        notes.append(f"columns only in old: {sorted(an - bn)}")
    if bn - an:
        notes.append(f"columns only in new: {sorted(bn - an)}")
    for c in sorted(an & bn):
        if a.schema.field(c).type != b.schema.field(c).type:
            notes.append(f"type of {c}: {a.schema.field(c).type} -> {b.schema.field(c).type}")
    if a.num_rows != b.num_rows:
        return [*notes, f"rows {a.num_rows} -> {b.num_rows}"]
    remapped = False
    for c in sorted(an & bn):
        va, vb = _values(a[c]), _values(b[c])
        if c in ID_COLUMNS and ids:
            mapped = np.array([ids.get(int(x), int(x)) for x in va], dtype=np.int64)
            remapped |= bool(np.any(mapped != va))
            va = mapped
        if isinstance(va, np.ndarray) and isinstance(vb, np.ndarray) and len(va) == len(vb):
            if va.dtype.kind == "f" or vb.dtype.kind == "f":
                ok = np.allclose(va.astype(np.float64), vb.astype(np.float64), rtol=rtol, atol=atol, equal_nan=True)
                if not ok:
                    d = np.nanmax(np.abs(va.astype(np.float64) - vb.astype(np.float64)))
                    notes.append(f"{c}: values differ (max abs {d:.3g})")
                elif not np.array_equal(va, vb, equal_nan=True):
                    d = np.nanmax(np.abs(va.astype(np.float64) - vb.astype(np.float64)))
                    notes.append(f"{c}: within tolerance (max abs {d:.3g})")
            elif not np.array_equal(va, vb):
                notes.append(f"{c}: {int(np.sum(va != vb))} of {len(va)} values differ")
        elif list(va) != list(vb):
            notes.append(f"{c}: values differ")
    if remapped:
        notes.append("clip ids remapped (identical after mapping by path)" if not notes else "clip ids remapped")
    return notes


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old", type=Path)
    ap.add_argument("new", type=Path)
    ap.add_argument("--rtol", type=float, default=1e-5)
    ap.add_argument("--atol", type=float, default=1e-6)
    a = ap.parse_args(argv)
    ids = clip_map(a.old, a.new)
    print(f"clip id map (old -> new): {dict(sorted(ids.items()))}")
    olds = {p.relative_to(a.old) for p in a.old.glob("**/*.parquet")}
    news = {p.relative_to(a.new) for p in a.new.glob("**/*.parquet")}
    for p in sorted(olds - news):
        print(f"{p}: only in old")
    for p in sorted(news - olds):
        print(f"{p}: only in new")
    n_same = 0
    for p in sorted(olds & news):
        notes = compare_table(pq.read_table(a.old / p), pq.read_table(a.new / p), ids, a.rtol, a.atol)
        if notes:
            print(f"{p}: " + "; ".join(notes))
        else:
            n_same += 1
    print(f"{n_same} of {len(olds & news)} common tables identical (ids included)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
