"""Registration of the generic analyses (the ``analyses`` package): ``analyses.clip_summary``."""

from __future__ import annotations

from mocapflow.framework.plugins import hookimpl


@hookimpl
def register_analyses() -> list[type]:
    from .summary import ClipSummary

    return [ClipSummary]
