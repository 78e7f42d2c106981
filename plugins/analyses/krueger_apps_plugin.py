"""Krüger et al. 2010 applications (§5.2, §5.3) as one plugin: reconstruction from sparse
markers with its evaluation, and fat-graph base poses."""
from __future__ import annotations

from mocapflow.framework.plugins import hookimpl


@hookimpl
def register_analyses() -> list[type]:
    from .fat_graph import FatGraph
    from .reconstruct import Reconstruct
    from .reconstruct_eval import ReconstructionEval

    return [Reconstruct, ReconstructionEval, FatGraph]
