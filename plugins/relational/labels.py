"""A clip's class label for templates and classification: the motions dataset's ``labels``
table (written by the ingest from a CSV or a name pattern) when it has one, else the
pattern over clip names."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np

    from mocapflow.framework.datasets import Dataset


def labels_of(
    motions: Dataset, clip_ids: Sequence[int] | np.ndarray, names: list[str], pattern: str
) -> list[str | None]:
    """Label of each clip (``clip_ids`` with their ``names``): from ``motions``' ``labels``
    table if the ingest wrote one (``formats.load`` with ``labels``/``label_pattern``), else
    the ``label`` group of ``pattern`` in the name (None where it does not match)."""
    if motions.has_table("labels"):
        from mocapflow.framework.labels import clip_labels_from_table

        return clip_labels_from_table(motions.table("labels"), [int(c) for c in clip_ids])
    import re

    from mocapflow.framework.errors import ConfigError

    rx = re.compile(pattern)
    if "label" not in rx.groupindex:
        raise ConfigError(f"pattern {pattern!r} needs a named group (?P<label>...)")
    return [m.group("label") if (m := rx.search(n)) else None for n in names]
