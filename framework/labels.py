"""Clip labels: the ``labels`` table an ingest writes from a CSV file (clip or span ->
label) or from a pattern over clip names, so that templates, classification and SQL read a
clip's class from one table instead of parsing file names each in its own way.

Table ``labels``: ``clip_id, name, start_frame, end_frame, label`` (frames at the dataset's
rate, half-open; both null for a label of the whole clip).
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Iterator, Mapping, Sequence
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


#: The largest frame a label may name (the ``labels`` table stores int32 frames).
_MAX_FRAME = 2**31 - 1


def _seconds(text: str, path: Path, line: int, column: str) -> float:
    try:
        seconds = float(text)
    except ValueError:
        raise ParseError(path, line, f"column {column!r}: expected seconds (a number), got {text!r}") from None
    if not math.isfinite(seconds):
        raise ParseError(path, line, f"column {column!r}: expected seconds (a finite number), got {text!r}")
    if seconds < 0:
        raise ParseError(path, line, f"column {column!r}: expected seconds >= 0, got {text!r}")
    return seconds


def _frame(seconds: float, fps: float, path: Path, line: int, column: str, clip: Mapping[str, Any]) -> int:
    """``seconds`` as a frame of ``clip`` (at ``fps``), checked against the clip's length."""
    frame = seconds * fps
    if not frame <= _MAX_FRAME:  # inf too
        raise ParseError(path, line, f"column {column!r}: {seconds:g} s is beyond any clip ({fps:g} fps)")
    n = clip.get("n_frames")
    if n is not None and n != "":
        n = int(n)
        # a start must fall inside the clip, an end at most at its end (half-open spans)
        last = n - 1 if column == "start" else n
        if round(frame) > last:
            raise ParseError(
                path,
                line,
                f"column {column!r}: {seconds:g} s is past the end of clip {clip.get('name')!r} "
                f"({n} frames, {n / fps:g} s at {fps:g} fps); expected a time within the clip",
            )
    return int(round(frame))


def _read_text(path: Path) -> str:
    """The file as UTF-8 text; a byte that is not UTF-8 is a :class:`ParseError` at its line."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"labels file {path}: {exc.strerror or exc}") from None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise ParseError(
            path,
            line,
            f"expected UTF-8 text, got byte 0x{data[exc.start]:02x} (a latin-1 or Windows file? save it as UTF-8)",
        ) from None


def _csv_rows(path: Path) -> Iterator[tuple[int, dict[str, str]]]:
    """``(line, row)`` of each non-blank row of a labels CSV, each with a clip and a label;
    a :class:`ParseError` for a bad header or row."""
    reader = csv.reader(io.StringIO(_read_text(path), newline=""), strict=True)
    try:
        raw_header = next(reader, [])
    except csv.Error as exc:
        raise ParseError(path, reader.line_num or 1, f"expected a CSV header: {exc}") from None
    header = [h.strip() for h in raw_header]
    missing = [c for c in ("clip", "label") if c not in header]
    if missing:
        raise ParseError(
            path, 1, f"expected a header with columns clip,label[,start,end]; missing {', '.join(missing)}"
        )
    while True:
        try:
            fields = next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            raise ParseError(path, reader.line_num, f"expected a CSV row: {exc}") from None
        line = reader.line_num
        if not any(f.strip() for f in fields):
            continue  # a blank line
        if len(fields) > len(header):
            raise ParseError(
                path,
                line,
                f"expected {len(header)} fields ({','.join(header)}), got {len(fields)}: "
                "quote a value that holds a comma",
            )
        row = {k: v.strip() for k, v in zip(header, fields, strict=False)}  # fewer fields: empty
        row.setdefault("clip", "")
        row.setdefault("label", "")
        if not row["clip"] or not row["label"]:
            raise ParseError(path, line, "expected a clip and a label")
        bad = next((ch for ch in row["clip"] + row["label"] if not ch.isprintable()), None)
        if bad is not None:
            raise ParseError(path, line, f"expected printable text for the clip and label, got {bad!r}")
        yield line, row


def csv_labels(path: str | Path, clips: Sequence[Mapping[str, Any]]) -> pa.Table:
    """Rows of a labels CSV for the given clips (dicts with ``clip_id, name, path, fps`` and
    ``n_frames``: spans are checked against it).

    Columns (header required): ``clip`` (a clip name, ``02_01``, or the end of its file path,
    ``02/02_01.amc``), ``label``, and optionally ``start``, ``end`` (seconds; empty or absent:
    the whole clip). Rows naming a clip this ingest did not read are skipped (one CSV can
    label a whole corpus); a CSV that labels none of them is an error. Every bad row is a
    :class:`ParseError` naming the file, the line and what was expected: a field more than the
    header has, a time that is not a finite number >= 0, a span that ends before it starts or
    lies past the clip's end, a byte that is not UTF-8.
    """
    path = Path(path)
    by_name: dict[str, list[Mapping[str, Any]]] = {}
    for c in clips:
        by_name.setdefault(str(c["name"]), []).append(c)
        by_name.setdefault(Path(str(c.get("path", ""))).name, []).append(c)
    rows = []
    for line, row in _csv_rows(path):
        key, label = row["clip"], row["label"]
        start_s = _seconds(row["start"], path, line, "start") if row.get("start") else None
        end_s = _seconds(row["end"], path, line, "end") if row.get("end") else None
        if start_s is not None and end_s is not None and end_s <= start_s:
            raise ParseError(path, line, f"end ({row['end']} s) must come after start ({row['start']} s)")
        wanted = key.replace("\\", "/")
        found = [
            c
            for c in by_name.get(Path(wanted).name, [])
            if "/" not in wanted or Path(str(c.get("path", ""))).as_posix().endswith("/" + wanted.lstrip("/"))
        ]
        for c in {id(c): c for c in found}.values():
            fps = float(c["fps"])
            start = _frame(start_s, fps, path, line, "start", c) if start_s is not None else None
            end = _frame(end_s, fps, path, line, "end", c) if end_s is not None else None
            if (start is None) != (end is None):
                start, end = start or 0, end if end is not None else int(c.get("n_frames", 0))
            if start is not None and end is not None and end <= start:
                raise ParseError(
                    path,
                    line,
                    f"the span {row.get('start') or 0}-{row.get('end') or 'end'} s of clip {c['name']!r} "
                    f"is shorter than a frame at {fps:g} fps",
                )
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
