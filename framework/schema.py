"""Arrow schemas of the tables mocapflow writes (Parquet on disk, views in DuckDB).

Conventions, stated once:

* every frame table has ``clip_id`` (int32) and ``frame`` (int32, 0-based within the clip);
* ``clip_id`` is the clip's identity, not its rank: a 31-bit hash of the source file's path
  relative to the ingest root (:func:`clip_id_of`), so adding, removing or breaking one
  file never renumbers another. Ids are sparse and unordered; tables list clips in path
  order, and code that needs a position looks it up (never ``clip_id`` as an array index);
* every segment or match table has ``clip_id, start_frame, end_frame`` where the range is
  **half-open**: ``end_frame`` is *exclusive* (``end_frame - start_frame`` frames); in a
  matcher step's tables (and everything printed or exported) these count frames of the
  take's own file, with the analysis-rate frames in columns named ``*_analysis``;
* feature vectors are fixed-size lists of float32;
* match tables of every matcher share :data:`MATCHES` (extra matcher-specific columns may
  follow), so SQL composes across matchers; ``rank`` is 1-based per ``query_id`` (1 = best)
  and lower ``cost`` is better;
* cleaners write :data:`DIGRESSIONS` (``data``) and :data:`EDITS` (``edits``) tables.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

CLIPS = pa.schema(
    [
        ("clip_id", pa.int32()),
        ("name", pa.string()),
        ("path", pa.string()),
        ("format", pa.string()),
        ("subject", pa.string()),
        ("fps", pa.float64()),
        ("n_frames", pa.int32()),
        ("skeleton", pa.string()),
        ("checksum", pa.string()),
        ("source_fps", pa.float64()),
        ("source_frames", pa.int32()),
    ]
)

#: Files that failed to read, with the id they would have had (``clip_id_of`` of their path).
REJECTS = pa.schema([("clip_id", pa.int32()), ("path", pa.string()), ("line", pa.int32()), ("message", pa.string())])

#: ``clips`` table of a markers dataset (``labels``: the marker names, in ``positions`` order).
MARKER_CLIPS = pa.schema(
    [
        ("clip_id", pa.int32()),
        ("name", pa.string()),
        ("path", pa.string()),
        ("format", pa.string()),
        ("fps", pa.float64()),
        ("n_frames", pa.int32()),
        ("n_markers", pa.int32()),
        ("labels", pa.list_(pa.string())),
        ("up_axis", pa.string()),
    ]
)

#: ``data`` table of a markers dataset: the clip's M*3 coordinates (metres, NaN in gaps), x y z
#: per marker in the order of that clip's ``clips.labels``.
MARKER_FRAMES = pa.schema(
    [
        ("clip_id", pa.int32()),
        ("frame", pa.int32()),
        pa.field(
            "positions", pa.list_(pa.float32()), metadata={"layout": "x,y,z per marker, in clips.labels order (metres)"}
        ),
    ]
)

#: ``data`` table of ``formats.export``: one row per written file.
EXPORTS = pa.schema([("clip_id", pa.int32()), ("name", pa.string()), ("file", pa.string())])

SKELETONS = pa.schema(
    [("skeleton", pa.string()), ("name", pa.string()), ("n_joints", pa.int32()), ("definition", pa.string())]
)

MATCHES = pa.schema(
    [
        ("query_id", pa.int32()),
        ("rank", pa.int32()),
        ("clip_id", pa.int32()),
        ("start_frame", pa.int32()),
        ("end_frame", pa.int32()),
        ("cost", pa.float64()),
    ]
)

#: Optional warping path column of match tables: pairs (query frame, database frame).
WARPING_PATH = pa.field("path", pa.list_(pa.list_(pa.int32(), 2)))

#: Match table of the matchers that align whole query segments (the default
#: :meth:`~.components.Matcher.run`, :func:`.matching.matches_table`): :data:`MATCHES`, the
#: cost per warping-path cell, the warping path (database frames within the clip).
MATCH_TABLE = MATCHES.append(pa.field("cost_normalized", pa.float64())).append(WARPING_PATH)

#: Query table beside a match table: where each query came from (``clip_id`` -1: a file;
#: frames half-open within that clip: of the take's own file, then at the analysis rate).
QUERIES = pa.schema(
    [
        ("query_id", pa.int32()),
        ("name", pa.string()),
        ("clip_id", pa.int32()),
        ("start_frame", pa.int32()),
        ("end_frame", pa.int32()),
        ("start_frame_analysis", pa.int32()),
        ("end_frame_analysis", pa.int32()),
    ]
)

#: Digression table of a cleaner (one row per input frame and analysed joint): ``value``
#: in [0, 1] (> 0.5: the cell is an error), ``flagged`` the decision, ``cue`` what flagged
#: it (null where nothing did). ``joint`` indexes the clip's skeleton joints.
DIGRESSIONS = pa.schema(
    [
        ("clip_id", pa.int32()),
        ("frame", pa.int32()),
        ("joint", pa.int32()),
        ("joint_name", pa.string()),
        ("value", pa.float32()),
        ("flagged", pa.bool_()),
        ("cue", pa.string()),
    ]
)

#: Edit table of a cleaner (one row per changed input cell): local rotations before and
#: after (w, x, y, z), the geodesic angle between them in degrees, the cue behind the edit.
EDITS = pa.schema(
    [
        ("clip_id", pa.int32()),
        ("frame", pa.int32()),
        ("joint", pa.int32()),
        ("joint_name", pa.string()),
        ("old_rotation", pa.list_(pa.float64(), 4)),
        ("new_rotation", pa.list_(pa.float64(), 4)),
        ("edit_deg", pa.float32()),
        ("cue", pa.string()),
    ]
)


#: Columns of a motions dataset's ``data`` table that rebuild its motions (``frame`` is implied).
MOTION_COLUMNS = ("clip_id", "root_translation")
#: The same in the layout before ``rotations.parquet`` (rotations per frame in ``data``): still read.
MOTION_COLUMNS_V1 = ("clip_id", "root_translation", "rotations")


def motion_frames() -> pa.Schema:
    """Schema of a motions dataset's frame table (``data``): one row per frame, the root's
    translation. The local rotations are in the ``rotations`` table (:func:`motion_rotations`),
    one row per clip. Joint positions are not stored: they are derived by forward kinematics
    (``Motion.positions``) where a step needs them.
    """
    return pa.schema(
        [
            ("clip_id", pa.int32()),
            ("frame", pa.int32()),
            pa.field("root_translation", pa.list_(pa.float32(), 3), metadata={"layout": "x,y,z of the root (metres)"}),
        ]
    )


#: Layout of ``rotations.quats`` (see :func:`motion_rotations`).
ROTATION_LAYOUT = "smallest-three float32, per joint, per kept component, the clip's frames; bytes split by position"


def motion_rotations() -> pa.Schema:
    """Schema of a motions dataset's ``rotations`` table: one row per clip, in ``clips``
    order, the clip's local joint rotations (unit quaternions w, x, y, z per joint, joints in
    the order of the skeleton definition) stored compactly and exactly to float32:

    * ``largest`` (J*T bytes, joint-major): which component (0..3 = w, x, y, z) of the
      quaternion has the largest magnitude; it is dropped, made positive (q and -q are one
      rotation) and rebuilt as ``sqrt(1 - sum of the other three squared)`` (>= 0.5, so the
      rebuild keeps float32 accuracy);
    * ``quats`` (J*3*T float32 values as bytes): the other three components in w, x, y, z
      order, laid out per joint, per component, then the frames (each series contiguous in
      time), the little-endian bytes split by position: byte 0 of every value, then byte 1,
      2, 3 (byte-stream split: smooth values share their high bytes, which zstd packs).
      ``motion_tables.unpack_rotations`` reads it back. 0.6-0.8x the bytes of the first
      layout's per-frame w, x, y, z rows.
    """
    return pa.schema(
        [
            ("clip_id", pa.int32()),
            ("n_frames", pa.int32()),
            ("n_joints", pa.int32()),
            ("largest", pa.binary()),
            pa.field("quats", pa.binary(), metadata={"layout": ROTATION_LAYOUT}),
        ]
    )


def clip_id_of(key: str) -> int:
    """Stable clip id of a source file: the first 31 bits of SHA-1 of ``key`` (its
    :func:`clip_keys` key, e.g. ``02/02_01.amc``), a non-negative int32 (-1 stays free for
    "not a clip"). Collisions are resolved by :func:`clip_ids_of`."""
    import hashlib

    return int.from_bytes(hashlib.sha1(key.encode("utf-8")).digest()[:4], "big") & 0x7FFFFFFF


def clip_keys(paths: list[str]) -> list[str]:
    """The key of each file path for :func:`clip_id_of`: its folder and file name
    (``02/02_01.amc``, POSIX separators), lengthened by one more folder at a time for the
    paths whose key would otherwise be shared (``amc/02/02_01.amc`` beside
    ``bvh/02/02_01.amc``). The key does not depend on where the files lie nor on which
    pattern found them, so every ingest of a take gives it the same id."""
    parts = [Path(p).as_posix().split("/") for p in paths]
    depth = [2] * len(parts)
    while True:
        keys = ["/".join(q[-d:]) for q, d in zip(parts, depth, strict=True)]
        groups: dict[str, list[int]] = {}
        for i, k in enumerate(keys):
            groups.setdefault(k, []).append(i)
        grow = [i for g in groups.values() if len(g) > 1 for i in g if depth[i] < len(parts[i])]
        if not grow:
            return keys
        for i in grow:
            depth[i] += 1


def clip_ids_of(keys: list[str]) -> list[int]:
    """Stable ids of distinct ``keys`` (:func:`clip_id_of`), collisions resolved
    deterministically: 31 bits give a collision among 10 000 files with probability about
    2 %, so rather than fail, the key that sorts later rehashes ``key + "#1"``, ``"#2"``...
    until its id is free. Only colliding keys depend on each other; which files *parse*
    never matters, since ids are given to every matched file before reading.
    """
    if len(set(keys)) != len(keys):
        raise ValueError("clip_ids_of needs distinct keys")
    taken: dict[int, str] = {}
    out: dict[str, int] = {}
    for key in sorted(keys):
        cid, salt = clip_id_of(key), 0
        while cid in taken:
            salt += 1
            cid = clip_id_of(f"{key}#{salt}")
        taken[cid] = key
        out[key] = cid
    return [out[k] for k in keys]


def fixed_list(x: np.ndarray) -> pa.FixedSizeListArray:
    """``(n, d)`` array -> fixed-size-list array without copying per row."""
    x = np.ascontiguousarray(x)
    return pa.FixedSizeListArray.from_arrays(pa.array(x.reshape(-1)), x.shape[1])


def fixed_list_to_numpy(col: pa.ChunkedArray | pa.Array, dtype: Any = np.float32) -> np.ndarray:
    """Fixed-size-list column -> ``(n, d)`` array."""
    if isinstance(col, pa.ChunkedArray):
        col = col.combine_chunks() if col.num_chunks != 1 else col.chunk(0)
    d = col.type.list_size
    flat = col.flatten().to_numpy(zero_copy_only=False)
    return np.asarray(flat, dtype=dtype).reshape(-1, d)
