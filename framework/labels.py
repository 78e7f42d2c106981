"""Clip labels: the ``labels`` table an ingest writes from a CSV file (clip or span ->
label) or from a pattern over clip names, so that templates, classification and SQL read a
clip's class from one table instead of parsing file names each in its own way.

Table ``labels``: ``clip_id, name, start_frame, end_frame, label`` (frames at the dataset's
rate, half-open; both null for a label of the whole clip).
"""

from __future__ import annotations

import csv
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa

from .errors import ConfigError, DataError, ParseError

LABELS = pa.schema(
    [
        ("clip_id", pa.int32()),
        ("name", pa.string()),
        pa.field("start_frame", pa.int32(), metadata={"unit": "frames at the dataset's fps; null: whole clip"}),
        pa.field("end_frame", pa.int32(), metadata={"unit": "frames at the dataset's fps, exclusive"}),
        ("label", pa.string()),
    ]
)


def pattern_labels(pattern: str, clips: Sequence[Mapping[str, Any]]) -> pa.Table:
    """One whole-clip row per clip whose ``name`` matches ``pattern`` (``re.search``): the
    named group ``label`` if the pattern has one, else its first group, else the match."""
    try:
        rx = re.compile(pattern)
    except re.error as exc:
        raise ConfigError(f"label_pattern {pattern!r} is not a regular expression: {exc}") from None
    group: str | int = "label" if "label" in rx.groupindex else (1 if rx.groups else 0)
    rows = []
    for c in clips:
        m = rx.search(str(c["name"]))
        if m and m.group(group):
            rows.append({"clip_id": c["clip_id"], "name": c["name"], "label": m.group(group)})
    return pa.Table.from_pylist(rows, schema=LABELS)


def _frame(text: str, fps: float, path: Path, line: int, column: str) -> int:
    try:
        seconds = float(text)
    except ValueError:
        raise ParseError(path, line, f"column {column!r}: expected seconds (a number), got {text!r}") from None
    if seconds < 0:
        raise ParseError(path, line, f"column {column!r}: expected seconds >= 0, got {text!r}")
    return int(round(seconds * fps))


def csv_labels(path: str | Path, clips: Sequence[Mapping[str, Any]]) -> pa.Table:
    """Rows of a labels CSV for the given clips (dicts with ``clip_id, name, path, fps``).

    Columns (header required): ``clip`` (a clip name, ``02_01``, or the end of its file path,
    ``02/02_01.amc``), ``label``, and optionally ``start``, ``end`` (seconds; empty or absent:
    the whole clip). Rows naming a clip this ingest did not read are skipped (one CSV can
    label a whole corpus); a CSV that labels none of them is an error.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise ConfigError(f"labels file {path}: {exc.strerror or exc}") from None
    reader = csv.DictReader(text.splitlines())
    header = [h.strip() for h in reader.fieldnames or []]
    missing = [c for c in ("clip", "label") if c not in header]
    if missing:
        raise ParseError(
            path, 1, f"expected a header with columns clip,label[,start,end]; missing {', '.join(missing)}"
        )
    by_name: dict[str, list[Mapping[str, Any]]] = {}
    for c in clips:
        by_name.setdefault(str(c["name"]), []).append(c)
        by_name.setdefault(Path(str(c.get("path", ""))).name, []).append(c)
    rows = []
    for line, raw in enumerate(reader, start=2):
        row = {(k or "").strip(): (v or "").strip() for k, v in raw.items()}
        key, label = row.get("clip", ""), row.get("label", "")
        if not key or not label:
            raise ParseError(path, line, "expected a clip and a label")
        wanted = key.replace("\\", "/")
        found = [
            c
            for c in by_name.get(Path(wanted).name, [])
            if "/" not in wanted or Path(str(c.get("path", ""))).as_posix().endswith("/" + wanted.lstrip("/"))
        ]
        for c in {id(c): c for c in found}.values():
            fps = float(c["fps"])
            start = _frame(row["start"], fps, path, line, "start") if row.get("start") else None
            end = _frame(row["end"], fps, path, line, "end") if row.get("end") else None
            if start is not None and end is not None and end <= start:
                raise ParseError(path, line, f"end ({row['end']} s) must come after start ({row['start']} s)")
            if (start is None) != (end is None):
                start, end = start or 0, end if end is not None else int(c.get("n_frames", 0))
            rows.append(
                {"clip_id": c["clip_id"], "name": c["name"], "start_frame": start, "end_frame": end, "label": label}
            )
    if clips and not rows:
        raise DataError(
            f"labels file {path}: no row names a clip of this ingest (clip names such as {clips[0]['name']!r})"
        )
    return pa.Table.from_pylist(rows, schema=LABELS)


def labels_table(
    clips: Sequence[Mapping[str, Any]], csv_path: str | Path | None = None, pattern: str | None = None
) -> pa.Table | None:
    """The ``labels`` table of an ingest: the CSV's rows, then the pattern's labels of the
    clips the CSV leaves unlabelled; None when neither is given."""
    if csv_path is None and pattern is None:
        return None
    parts = [csv_labels(csv_path, clips)] if csv_path is not None else []
    if pattern is not None:
        have = set(parts[0]["clip_id"].to_pylist()) if parts else set()
        parts.append(pattern_labels(pattern, [c for c in clips if c["clip_id"] not in have]))
    return pa.concat_tables(parts) if len(parts) > 1 else parts[0]


def clip_labels_from_table(table: pa.Table, clip_ids: Sequence[int]) -> list[str | None]:
    """The label of each clip in ``clip_ids`` from a ``labels`` table: its whole-clip label,
    else the one label all its spans share; None when it has none (or spans disagree)."""
    whole: dict[int, str] = {}
    spans: dict[int, set[str]] = {}
    for r in table.select(["clip_id", "start_frame", "label"]).to_pylist():
        if r["start_frame"] is None:
            whole.setdefault(int(r["clip_id"]), r["label"])
        else:
            spans.setdefault(int(r["clip_id"]), set()).add(r["label"])
    out: list[str | None] = []
    for c in clip_ids:
        s = spans.get(int(c), set())
        out.append(whole.get(int(c)) or (next(iter(s)) if len(s) == 1 else None))
    return out
