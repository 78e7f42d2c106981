"""Registration of the Krüger et al. 2010 components (the ``similarity`` package).

Feature sets ``features.end_effectors`` and ``features.pca``; the kNN indexes
``indexes.kdtree``, ``indexes.sharded`` and, with the ``ann`` extra, ``indexes.hnsw``; the
global matchers ``matchers.lng``, ``matchers.sdtw`` and ``matchers.logical``; the analyses
built on them (nearest poses, distance correlation, reconstruction, fat-graph base poses);
and the ``mocapflow search`` command. Every import is inside a hook so that loading this
module (``mocapflow --help``) imports no numerical library.
"""
from __future__ import annotations

from mocapflow.framework.plugins import hookimpl


@hookimpl
def register_features() -> list[type]:
    from .end_effectors import EndEffectorFeatures
    from .pca import PosePCA

    return [EndEffectorFeatures, PosePCA]


@hookimpl
def register_indexes() -> list[type]:
    from importlib.util import find_spec

    from .kdtree import KDTreeIndex
    from .sharded import ShardedIndex

    if find_spec("hnswlib") is None:  # indexes.hnsw exists with the 'ann' extra only
        return [KDTreeIndex, ShardedIndex]
    from .hnsw import HNSWIndex

    return [KDTreeIndex, HNSWIndex, ShardedIndex]


@hookimpl
def register_matchers() -> list[type]:
    from .lng import LazyNeighborhoodGraph
    from .logical import LogicalSearch
    from .sdtw import SubsequenceDTW

    return [LazyNeighborhoodGraph, SubsequenceDTW, LogicalSearch]


@hookimpl
def register_analyses() -> list[type]:
    from .correlation import DistanceCorrelationStudy
    from .fat_graph import FatGraph
    from .knn_query import NearestPoses
    from .reconstruct import Reconstruct
    from .reconstruct_eval import ReconstructionEval

    return [NearestPoses, DistanceCorrelationStudy, Reconstruct, ReconstructionEval, FatGraph]


@hookimpl
def register_commands() -> list[type]:
    from .search_command import SearchCommand

    return [SearchCommand]
