"""Built-in file formats (readers, writers) and the ingest step, as one plugin."""
from __future__ import annotations

from mocapflow.framework.plugins import hookimpl


@hookimpl
def register_formats() -> list[type]:
    return []
