"""The Python API: a thin facade over the registered components the pipelines use.

Every call goes through the registries (built once, lazily, by
:func:`mocapflow.framework.plugins.load_registries`), so a third-party plugin's formats,
feature sets, indexes, matchers and cleaners are available here under their names too.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


def registries():
    """The registries of every installed plugin (built once per process)."""
    from mocapflow.framework.plugins import default_registries

    return default_registries()


def _format_for(path: Path, *, writing: bool):
    return registries().motion_format(path, writing=writing)


def read(path: str | Path):
    """Read a motion file with the registered format for its extension (ASF found beside AMC).

    Returns a :class:`~mocapflow.framework.Motion` (rotations, metres; ``.positions`` is
    ``(T, J, 3)`` in metres).
    """
    path = Path(path).expanduser()
    return _format_for(path, writing=False).read(path)


def write(motion, path: str | Path) -> None:
    """Write ``motion`` with the registered format for the extension of ``path``, atomically."""
    path = Path(path).expanduser()
    path.parent.mkdir(parents=True, exist_ok=True)
    _format_for(path, writing=True).write_atomic(motion, path)


def _motions(motions) -> list:
    from mocapflow.framework.motion import Motion

    if isinstance(motions, (Motion, str, Path)):
        motions = [motions]
    out = []
    for m in motions:
        if isinstance(m, Motion):
            out.append(m)
        elif Path(m).expanduser().is_dir():
            out.extend(read(f) for f in _motion_files(Path(m).expanduser()))
        else:
            out.append(read(m))
    return out


def _motion_files(folder: Path) -> list[Path]:
    """The files below ``folder`` that a registered motion format reads, in path order."""
    from mocapflow.framework.errors import ConfigError

    exts = {e for _, c in registries()["formats"] for e in c.extensions if c.produces == "motion"}
    files = sorted(f for f in folder.rglob("*") if f.suffix.lower() in exts and f.is_file())
    if not files:
        raise ConfigError(f"{folder}: no motion file in this folder or below ({', '.join(sorted(exts))})")
    return files


def features(name: str, motions, **params: Any):
    """Per-frame features of ``motions`` (Motions or paths) with ``features.<name>``.

    Returns an ndarray of float32, shape ``(total frames, dim)``, clips concatenated in order.
    """
    from mocapflow.framework.database import MotionDatabase

    db = MotionDatabase(_motions(motions))
    return registries()["features"].get(name)(params).fit(db).transform(db)


class Database:
    """Motions, their features and an index over them, ready for similarity search.

    Parameters
    ----------
    motions : sequence of Motion or paths, or a folder
        The clips (a folder: every motion file below it, in path order); clip ``i`` gets
        ``clip_id == i``.
    features : str
        Feature set (``features.<name>``); ``feature_params`` go to it.
    index : str
        Index (``indexes.<name>``) built over the features.
    fps : float or None
        Resample every clip (and each query) to this rate, Hz (the pipelines use 30); None keeps them.
    """

    def __init__(
        self,
        motions,
        features: str = "end_effectors",
        index: str = "kdtree",
        *,
        fps: float | None = 30.0,
        feature_params: dict | None = None,
        index_params: dict | None = None,
    ) -> None:
        from mocapflow.framework.database import MotionDatabase
        from mocapflow.framework.matching import SearchSpace
        from mocapflow.framework.normalize import resample

        regs = registries()
        self.fps = fps
        ms = [resample(m, fps) if fps else m for m in _motions(motions)]
        self.motions = MotionDatabase(ms)
        self.feature_set = regs["features"].get(features)(feature_params or {}).fit(self.motions)
        x = self.feature_set.transform(self.motions)
        self.index = regs["indexes"].get(index)(index_params or {}).build(x)
        clip_id, frame = self.motions.frame_ids
        self.clip_names = {int(c): m.name for c, m in zip(self.motions.clip_ids, self.motions, strict=True)}
        self.space = SearchSpace(clip_id, frame, self.index, x, clip_names=self.clip_names)

    def search(self, query, matcher: str = "search", count: int = 10, **params: Any):
        """Segments most similar to ``query`` (a Motion or path, resampled to the database rate).

        Returns the shared match table (pyarrow Table: ``query_id, rank, clip_id, start_frame,
        end_frame, cost, cost_normalized, path``, frames half-open, plus ``clip`` names).
        """
        import pyarrow as pa

        from mocapflow.framework.matching import matches_table
        from mocapflow.framework.normalize import resample

        q = _motions(query)[0]
        q = resample(q, self.fps) if self.fps else q
        m = registries()["matchers"].get(matcher)({"count": count, **params})
        res = m.match(self.feature_set.transform(q), self.space)
        table = matches_table([0], [res], self.space)
        return table.append_column(
            "clip", pa.array([self.clip_names[c] for c in table["clip_id"].to_pylist()], pa.string())
        )


def clean(take, context=(), **params: Any):
    """Clean ``take`` against ``context`` takes with ``cleaners.mdm`` (Aristidou 2018).

    Returns ``(cleaned Motion, edits)``: the edits are an Arrow table (one row per edited
    joint and frame).
    """
    cleaner = registries()["cleaners"].get("mdm")({"write_bvh": False, "heatmaps": False, **params})
    return cleaner.repair(_motions(take)[0], _motions(context))
