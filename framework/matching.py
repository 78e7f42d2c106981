"""The matcher contract: search spaces, ranked matches and the shared match table.

A matcher reduces one query to candidate path ends (cost, first row, length) and keeps
ranked, non-overlapping matches with :func:`select_matches`, the same rule for every
matcher so their results compare one to one. Rows are index rows (= features table rows);
:class:`SearchSpace` maps them to ``(clip_id, frame)``.
"""

from __future__ import annotations

import bisect
import hashlib
import re
from collections.abc import Callable, Hashable, Mapping
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np
import pyarrow as pa
from pydantic import Field, field_validator

from . import schema
from .errors import ConfigError, DataError
from .params import Params

#: Columns of a match table (:data:`~mocapflow.framework.schema.MATCH_TABLE`).
MATCH_COLUMNS = schema.MATCH_TABLE


class NeighbourIndex(Protocol):
    """What a search space needs of an index (:class:`~mocapflow.framework.Index`)."""

    def query(self, x: np.ndarray, k: int, radius: float | None = None) -> tuple[np.ndarray, np.ndarray]: ...


@dataclass(frozen=True)
class SearchSpace:
    """The searched database: frame id (``clip_id``, ``frame``: int32 (n,)) of every index
    row, optionally a built ``index`` over the rows, their ``features`` float32 (n, d) and
    ``clip_names`` by clip id (plots). :meth:`memo` keeps arrays derived once per space.

    ``excluded`` are index rows ``(lo, hi)`` (closed) no match may overlap: the query's own
    span (:func:`self_rows`), set per query by :meth:`excluding`; a matcher passes it to
    :func:`select_matches` (and the core drops any match overlapping it anyway)."""

    clip_id: np.ndarray
    frame: np.ndarray
    index: NeighbourIndex | None = None
    features: np.ndarray | None = None
    clip_names: dict[int, str] | None = None
    excluded: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        cid = np.asarray(self.clip_id, np.int32)
        fr = np.asarray(self.frame, np.int32)
        if cid.shape != fr.shape or cid.ndim != 1:
            raise DataError(f"clip_id and frame must be 1-d of one length, got {cid.shape} and {fr.shape}")
        object.__setattr__(self, "clip_id", cid)
        object.__setattr__(self, "frame", fr)
        if self.features is not None:
            x = np.ascontiguousarray(self.features, dtype=np.float32)
            if x.ndim != 2 or x.shape[0] != len(cid):
                raise DataError(f"features must be (n_rows={len(cid)}, dim), got {x.shape}")
            object.__setattr__(self, "features", x)

    @property
    def n_rows(self) -> int:
        return len(self.clip_id)

    @cached_property
    def continues(self) -> np.ndarray:
        """bool (n,): row ``j`` is the frame after row ``j-1`` in the same clip (where a path
        may step from ``j-1`` to ``j``: none crosses a clip boundary or a gap)."""
        c = np.zeros(self.n_rows, bool)
        c[1:] = (self.clip_id[1:] == self.clip_id[:-1]) & (self.frame[1:] == self.frame[:-1] + 1)
        return c

    @cached_property
    def _memo(self) -> dict[Hashable, Any]:
        return {}

    def excluding(self, rows: tuple[int, int] | None) -> SearchSpace:
        """This space with ``rows`` excluded (:attr:`excluded`); arrays and memo shared."""
        if rows == self.excluded:
            return self
        view = replace(self, excluded=rows)
        view.__dict__["_memo"] = self._memo  # derived arrays (block boxes...) stay computed once
        if "continues" in self.__dict__:
            view.__dict__["continues"] = self.__dict__["continues"]
        return view

    def memo(self, key: Hashable, compute: Callable[[], Any]) -> Any:
        """``compute()`` once per space and ``key`` (an algorithm's derived arrays)."""
        if key not in self._memo:
            self._memo[key] = compute()
        return self._memo[key]

    def neighbors(self, x: np.ndarray, k: int, radius: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The index's kNN of ``x`` (m, d): ``(dist, ids)`` each (m, k), as :meth:`.Index.query`."""
        if self.index is None:
            raise DataError("this search space has no index (SearchSpace.index)")
        dist, ids = self.index.query(np.ascontiguousarray(x, dtype=np.float32), k, radius)
        return np.asarray(dist), np.asarray(ids)


@dataclass
class QueryMatches:
    """Ranked matches of one query: index rows ``[start, end)``, ``length`` cells per warping
    path, ``paths[r]`` its ``(query frame, row)`` pairs."""

    start: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    end: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    cost: np.ndarray = field(default_factory=lambda: np.zeros(0))
    length: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    paths: list[np.ndarray] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.cost)

    def columns(self) -> dict[str, np.ndarray]:
        """Matcher-specific columns, one value per match, appended to the match table
        (none here; a subclass adds its own)."""
        return {}

    def validate(self, space: SearchSpace, what: str = "matches") -> None:
        """Raise :class:`DataError` unless the arrays agree and the rows lie in ``space``."""
        n = len(self.cost)
        if not (len(self.start) == len(self.end) == len(self.length) == n) or (self.paths and len(self.paths) != n):
            raise DataError(f"{what}: start, end, cost, length (and paths) must have one length")
        s, e = np.asarray(self.start), np.asarray(self.end)
        if n and (s.min() < 0 or e.max() > space.n_rows or np.any(e <= s)):
            raise DataError(f"{what}: rows [start, end) must lie within the {space.n_rows} rows and be non-empty")


class IntervalSet:
    """Disjoint closed row intervals ``[start, end]``, sorted; O(log n) overlap tests."""

    def __init__(self) -> None:
        self._lo: list[int] = []
        self._hi: list[int] = []

    def overlaps(self, start: int, end: int) -> bool:
        pos = bisect.bisect_right(self._lo, end)  # intervals starting at or before end
        return bool(pos) and self._hi[pos - 1] >= start

    def add(self, start: int, end: int) -> bool:
        """Insert unless it overlaps one already there; whether it was inserted."""
        if self.overlaps(start, end):
            return False
        pos = bisect.bisect_right(self._lo, end)
        self._lo.insert(pos, start)
        self._hi.insert(pos, end)
        return True

    def __len__(self) -> int:
        return len(self._lo)


def select_matches(
    end: np.ndarray,
    start: np.ndarray,
    cost: np.ndarray,
    length: np.ndarray,
    *,
    count: int,
    max_cost: float | None,
    rank_by: str,
    min_frames: int = 1,
    excluded: tuple[int, int] | None = None,
) -> np.ndarray:
    """Positions (int64, best first) of the greedy ranked, non-overlapping choice among
    candidate path ends: by ascending ``cost`` (or ``cost / length``), each kept when rows
    ``[start, end]`` overlap no kept match nor the ``excluded`` rows (closed; the query's
    own span, :attr:`SearchSpace.excluded`), until ``count`` or ``max_cost``; candidates
    spanning fewer than ``min_frames`` rows (a query squashed onto a few frames) skipped."""
    key = cost / np.maximum(length, 1) if rank_by == "normalized" else np.asarray(cost, np.float64)
    ok = np.isfinite(key)
    if max_cost is not None:
        ok &= key <= max_cost
    if min_frames > 1:
        ok &= (np.asarray(end) - np.asarray(start) + 1) >= min_frames
    cand = np.flatnonzero(ok)
    kept: list[int] = []
    taken = IntervalSet()
    if excluded is not None:  # the query's own span: no match may overlap it
        taken.add(*excluded)
    chunk = max(64, 32 * count)
    while cand.size and len(kept) < count:
        # the chunk best candidates, in order (argpartition keeps this O(n) for sDTW)
        if cand.size > chunk:
            part = np.argpartition(key[cand], chunk)[:chunk]
            head, cand = cand[part], np.delete(cand, part)
        else:
            head, cand = cand, cand[:0]
        head = head[np.lexsort((end[head], key[head]))]
        for c in head:
            if not taken.add(int(start[c]), int(end[c])):
                continue
            kept.append(int(c))
            if len(kept) == count:
                break
    return np.asarray(kept, np.int64)


#: ``exclude_self`` modes: ``span`` the query's span widened by half its length on each side
#: (the exclusion zone of matrix-profile practice), ``clip`` its whole clip, ``off`` none.
EXCLUDE_SELF = ("span", "clip", "off")


def self_rows(space: SearchSpace, clip_id: int, start: int, end: int, mode: str) -> tuple[int, int] | None:
    """Index rows ``(lo, hi)`` a query cut from frames ``[start, end)`` of database clip
    ``clip_id`` (-1: not in the database) excludes: ``mode`` ``span`` its frames widened by
    ``ceil(length / 2)`` on each side, ``clip`` the whole clip, ``off`` nothing (None)."""
    if mode not in EXCLUDE_SELF:
        raise ConfigError(f"exclude_self must be one of {', '.join(EXCLUDE_SELF)}, got {mode!r}")
    if mode == "off" or clip_id < 0:
        return None
    mask = space.clip_id == clip_id
    if mode == "span":
        zone = (end - start + 1) // 2
        mask &= (space.frame >= start - zone) & (space.frame < end + zone)
    rows = np.flatnonzero(mask)
    return (int(rows[0]), int(rows[-1])) if rows.size else None


def drop_excluded(res: QueryMatches, rows: tuple[int, int] | None) -> QueryMatches:
    """``res`` without matches overlapping ``rows`` (for matchers that rank without
    :func:`select_matches`); ranks close up."""
    if rows is None or not len(res):
        return res
    keep = (np.asarray(res.end) <= rows[0]) | (np.asarray(res.start) > rows[1])
    if keep.all():
        return res
    return QueryMatches(
        res.start[keep],
        res.end[keep],
        res.cost[keep],
        res.length[keep],
        [p for p, k in zip(res.paths, keep, strict=False) if k],
    )


#: clip id -> ``(analysis fps, source fps, source frames)``: how a clip's analysis-rate rows
#: map to frames of its own file (:func:`in_source_units`).
ClipUnits = Mapping[int, tuple[float, float, int]]

#: Columns of a match table in the users' units (:func:`in_source_units`), in order; matcher
#: specific columns follow.
USER_MATCH_COLUMNS = (
    "query_id",
    "rank",
    "clip_id",
    "start_frame",
    "end_frame",
    "cost",
    "cost_normalized",
    "fps",
    "start_s",
    "end_s",
    "start_frame_analysis",
    "end_frame_analysis",
    "fps_analysis",
    "path_analysis",
)


def source_span(
    start: np.ndarray, end: np.ndarray, scale: np.ndarray, n_src: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Analysis-rate frames ``[start, end)`` -> frames of the source file (``scale`` = source
    fps / analysis fps), half-open, at least one frame, within its ``n_src`` frames."""
    sf = np.clip(np.round(np.asarray(start) * scale), 0, np.maximum(n_src - 1, 0)).astype(np.int32)
    ef = np.maximum(np.minimum(np.round(np.asarray(end) * scale), n_src), sf + 1).astype(np.int32)
    return sf, ef


def analysis_span(start: int, end: int, source_fps: float, fps: float, n_frames: int) -> tuple[int, int]:
    """Source-file frames ``[start, end)`` -> analysis-rate frames of a clip of ``n_frames``
    at ``fps`` (the inverse of :func:`source_span`; at least one frame)."""
    scale = fps / source_fps if source_fps > 0 else 1.0
    a = int(np.clip(round(start * scale), 0, max(n_frames - 1, 0)))
    b = int(max(min(round(end * scale), n_frames), a + 1))
    return a, b


def in_source_units(table: pa.Table, clips: ClipUnits | None) -> pa.Table:
    """A match table (:data:`~.schema.MATCH_TABLE`: frames at the analysis rate) in the one
    convention users read (:data:`USER_MATCH_COLUMNS`, then any further columns):

    ``start_frame``/``end_frame`` are frames of the take's own file (half-open), ``fps`` its
    rate, ``start_s``/``end_s`` seconds from the take's start; the analysis-rate frames stay
    in ``start_frame_analysis``/``end_frame_analysis`` (rate ``fps_analysis``) and the warping
    path (query frame, database frame) in ``path_analysis``. A clip missing from ``clips``
    (no source rates known) keeps its analysis frames, with null rates and seconds."""
    cid = table["clip_id"].to_numpy()
    known = np.array([clips is not None and int(c) in clips for c in cid], bool)
    rates = np.array(
        [clips[int(c)] if k and clips is not None else (np.nan, np.nan, -1) for c, k in zip(cid, known, strict=True)],
        np.float64,
    ).reshape(-1, 3)
    a_fps, s_fps, n_src = rates[:, 0], rates[:, 1], rates[:, 2]
    scale = np.where(known, s_fps / np.maximum(np.nan_to_num(a_fps, nan=1.0), 1e-12), 1.0)
    n_src = np.where(known, n_src, np.iinfo(np.int32).max)
    a, b = table["start_frame"].to_numpy(), table["end_frame"].to_numpy()
    sf, ef = source_span(a, b, scale, n_src)
    cols: dict[str, Any] = {c: table[c] for c in ("query_id", "rank", "clip_id")}
    cols["start_frame"], cols["end_frame"] = pa.array(sf), pa.array(ef)
    cols["cost"] = table["cost"]
    if "cost_normalized" in table.column_names:
        cols["cost_normalized"] = table["cost_normalized"]
    cols["fps"] = pa.array(s_fps, pa.float64(), mask=~known)
    cols["start_s"] = pa.array(sf / s_fps, pa.float64(), mask=~known)
    cols["end_s"] = pa.array(ef / s_fps, pa.float64(), mask=~known)
    cols["start_frame_analysis"] = pa.array(a.astype(np.int32))
    cols["end_frame_analysis"] = pa.array(b.astype(np.int32))
    cols["fps_analysis"] = pa.array(a_fps, pa.float64(), mask=~known)
    if "path" in table.column_names:
        cols["path_analysis"] = table["path"]
    done = {"path", "start_frame", "end_frame", *cols}
    for name in table.column_names:
        if name not in done:
            cols[name] = table[name]
    return pa.table(cols)


def min_frames_of(min_span: float, query_frames: int) -> int:
    """Database rows a match must span: ``min_span`` times the query length, at least 1."""
    return max(1, int(np.ceil(min_span * query_frames - 1e-9)))


def matches_table(query_ids: list[int], results: list[QueryMatches], space: SearchSpace) -> pa.Table:
    """Match table (:data:`~.schema.MATCH_TABLE`, within-clip frames) of ``results[i]``
    labelled ``query_ids[i]``; each result needs one path per match."""
    for q, r in zip(query_ids, results, strict=True):
        r.validate(space, f"query {q}")
        if len(r.paths) != len(r):
            raise DataError(f"query {q}: {len(r)} matches but {len(r.paths)} warping paths")
    qid, rank, s_all, e_all, c_all, l_all, offsets, flat = [], [], [], [], [], [], [0], []
    for q, r in zip(query_ids, results, strict=True):
        n = len(r)
        qid.append(np.full(n, q, np.int32))
        rank.append(np.arange(1, n + 1, dtype=np.int32))
        s_all.append(r.start)
        e_all.append(r.end)
        c_all.append(r.cost)
        l_all.append(r.length)
        for p in r.paths:
            flat.append(np.stack([p[:, 0], space.frame[p[:, 1]]], axis=1).astype(np.int32))
            offsets.append(offsets[-1] + len(p))

    def cat(xs: list[np.ndarray], dt: Any) -> np.ndarray:
        return np.concatenate(xs).astype(dt) if xs else np.zeros(0, dt)

    start, end = cat(s_all, np.int64), cat(e_all, np.int64)
    cost, length = cat(c_all, np.float64), cat(l_all, np.float64)
    pairs = np.concatenate(flat) if flat else np.zeros((0, 2), np.int32)
    path = pa.ListArray.from_arrays(
        pa.array(np.asarray(offsets, np.int32)), pa.FixedSizeListArray.from_arrays(pa.array(pairs.reshape(-1)), 2)
    )
    extra: dict[str, list[np.ndarray]] = {}
    for r in results:
        for name, values in r.columns().items():
            extra.setdefault(name, []).append(np.asarray(values))
    cols = {
        "query_id": pa.array(cat(qid, np.int32)),
        "rank": pa.array(cat(rank, np.int32)),
        "clip_id": pa.array(space.clip_id[start]),
        "start_frame": pa.array(space.frame[start]),
        "end_frame": pa.array((space.frame[end - 1] + 1).astype(np.int32)),
        "cost": pa.array(cost),
        "cost_normalized": pa.array(cost / np.maximum(length, 1)),
        "path": path.cast(schema.WARPING_PATH.type),
    }
    table = pa.table(cols, schema=schema.MATCH_TABLE)
    for name, parts in extra.items():
        if len(parts) != len(results):
            raise DataError(f"column {name!r}: some results lack it")
        table = table.append_column(name, pa.array(np.concatenate(parts)))
    return table


class MatchParams(Params):
    """Parameters of a matcher on the default step: which queries, and which matches are kept."""

    count: int = Field(10, ge=1, description="matches kept per query")
    max_cost: float | None = Field(None, ge=0, description="ceiling on the ranking cost; worse matches are dropped")
    rank_by: Literal["cost", "normalized"] = Field(
        "cost", description="rank by accumulated cost or by cost per path cell"
    )
    min_span: float = Field(
        0.5,
        ge=0,
        le=10,
        description=(
            "drop matches spanning fewer database frames than this fraction of the query length "
            "(default 0.5: no whole query squashed onto a few frames; 0: all, as in the paper)"
        ),
    )
    exclude_self: Literal["span", "clip", "off"] = Field(
        "span",
        description=(
            "a query cut from a database clip: no match overlapping its span widened by half its "
            "length on each side (span), none in its clip (clip), or no exclusion (off)"
        ),
    )
    queries: list[str] = Field(
        default_factory=list,
        description=(
            "query segments 'clip_or_file[:start-end]' (frames, end exclusive; or seconds with 's'); "
            "empty: every clip of the query input"
        ),
    )

    @field_validator("exclude_self", mode="before")
    @classmethod
    def _yaml_off(cls, v: Any) -> Any:
        """YAML 1.1 reads an unquoted ``off`` as false: take it as ``"off"``."""
        return "off" if v is False else v


_RANGE = re.compile(r"^(?P<a>\d+(?:\.\d+)?)(?P<ua>s?)-(?P<b>\d+(?:\.\d+)?)(?P<ub>s?)$")


@dataclass(frozen=True)
class QuerySpec:
    """A parsed ``SOURCE[:START-END]``; ``start``/``end`` in frames, or seconds if ``seconds``."""

    source: str
    start: float | None = None
    end: float | None = None
    seconds: bool = False

    def frames(self, fps: float, n_frames: int, units: str = "") -> tuple[int, int]:
        """Half-open frame range within a clip of ``n_frames`` at ``fps`` (``units`` says
        which frames, for the error: e.g. "frames of the take's own file at 120 fps")."""
        if self.start is None or self.end is None:
            return 0, n_frames
        scale = fps if self.seconds else 1.0
        a, b = int(round(self.start * scale)), int(round(self.end * scale))
        if not 0 <= a < b <= n_frames:
            of = f" ({units}" + (f"; 0s-{n_frames / fps:g}s in seconds)" if fps > 0 and units else ")") if units else ""
            raise ConfigError(f"query {self.text()!r}: frames [{a}, {b}) outside the clip's {n_frames} frames{of}")
        return a, b

    def text(self) -> str:
        if self.start is None or self.end is None:
            return self.source
        if self.seconds:
            return f"{self.source}:{self.start:g}s-{self.end:g}s"
        return f"{self.source}:{int(self.start)}-{int(self.end)}"


#: The longest query text, and the longest name between two ``/`` in it (a file name's limit).
MAX_QUERY_CHARS, MAX_QUERY_NAME_BYTES = 4096, 255


def _check_query_source(text: str) -> None:
    shown = f"{text[:40]!r}{'...' if len(text) > 40 else ''}"
    if not text.strip():
        raise ConfigError("query: expected a motion file or a database clip, got an empty string")
    if "\x00" in text:
        raise ConfigError(f"query {shown}: a NUL character cannot be in a file or clip name")
    if len(text) > MAX_QUERY_CHARS:
        raise ConfigError(f"query {shown}: {len(text)} characters; at most {MAX_QUERY_CHARS}")
    longest = max(len(part.encode("utf-8", "surrogateescape")) for part in text.split("/"))
    if longest > MAX_QUERY_NAME_BYTES:
        raise ConfigError(
            f"query {shown}: a name of {longest} bytes; a file or clip name has at most {MAX_QUERY_NAME_BYTES}"
        )


def parse_query_spec(text: str) -> QuerySpec:
    """``"walk.amc:30-120"`` -> ``QuerySpec("walk.amc", 30, 120)``; no range: the whole clip.
    A source that cannot name a file or clip (empty, a NUL character, a name longer than a
    file name may be) is a :class:`ConfigError`."""
    _check_query_source(text)
    source, sep, rng = text.rpartition(":")
    m = _RANGE.match(rng) if sep else None
    if not m:
        return QuerySpec(text)
    if bool(m["ua"]) != bool(m["ub"]):
        raise ConfigError(f"query {text!r}: give both ends in frames or both in seconds ('1.5s-3s')")
    secs = bool(m["ua"])
    a, b = float(m["a"]), float(m["b"])
    if not secs and (a != int(a) or b != int(b)):
        raise ConfigError(f"query {text!r}: frame numbers must be integers (or add 's' for seconds)")
    if b <= a:
        raise ConfigError(f"query {text!r}: empty range (end is exclusive)")
    return QuerySpec(source, a, b, secs)


def query_files_fingerprint(queries: Any, base_dir: Path) -> str:
    """Digest of the query files named in ``queries`` (path, size, mtime; non-strings
    skipped); "" when none."""
    h, files = hashlib.sha256(), 0
    for text in queries or ():
        if not isinstance(text, str):
            continue
        p = Path(parse_query_spec(text).source).expanduser()
        p = p if p.is_absolute() else Path(base_dir) / p
        if p.is_file():
            st = p.stat()
            h.update(f"{p}|{st.st_size}|{st.st_mtime_ns}\n".encode())
            files += 1
    return h.hexdigest()[:24] if files else ""
