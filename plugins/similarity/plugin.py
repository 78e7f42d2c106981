"""Registration of the Krüger et al. 2010 components (the ``similarity`` package).

Feature sets ``features.end_effectors`` and ``features.pca``; the kNN indexes
``indexes.kdtree``, ``indexes.sharded`` and, with the ``ann`` extra, ``indexes.hnsw``; the
global matchers ``matchers.search`` (the default: certified subsequence DTW), ``matchers.lng``
(the paper's lazy neighbourhood graph), ``matchers.sdtw`` and ``matchers.logical``; the analyses
built on them (nearest poses, distance correlation, reconstruction, fat-graph base poses);
and the ``mocapflow search`` command. Every import is inside a hook so that loading this
module (``mocapflow --help``) imports no numerical library.
"""

from __future__ import annotations

from mocapflow.framework.plugins import hookimpl


@hookimpl
def register_features() -> list[type]:
    from .knn.end_effectors import EndEffectorFeatures
    from .knn.pca import PosePCA

    return [EndEffectorFeatures, PosePCA]


@hookimpl
def register_indexes() -> list[type]:
    from importlib.util import find_spec

    from .knn.kdtree import KDTreeIndex
    from .knn.sharded import ShardedIndex

    if find_spec("hnswlib") is None:  # indexes.hnsw exists with the 'ann' extra only
        return [KDTreeIndex, ShardedIndex]
    from .knn.hnsw import HNSWIndex

    return [KDTreeIndex, HNSWIndex, ShardedIndex]


@hookimpl
def register_matchers() -> list[type]:
    from .search.certified import CertifiedSearch
    from .search.lng import LazyNeighborhoodGraph
    from .search.logical import LogicalSearch
    from .search.sdtw import SubsequenceDTW

    return [CertifiedSearch, LazyNeighborhoodGraph, SubsequenceDTW, LogicalSearch]


@hookimpl
def register_analyses() -> list[type]:
    from .applications.correlation import DistanceCorrelationStudy
    from .applications.fat_graph import FatGraph
    from .applications.reconstruct_eval import ReconstructionEval
    from .applications.reconstruct_markers import ReconstructMarkers
    from .applications.reconstruct_steps import Reconstruct, ReconstructionPrior
    from .knn.knn_query import NearestPoses

    return [
        NearestPoses,
        DistanceCorrelationStudy,
        ReconstructionPrior,
        Reconstruct,
        ReconstructMarkers,
        ReconstructionEval,
        FatGraph,
    ]


@hookimpl
def register_commands() -> list[type]:
    from .applications.reconstruct_command import ReconstructCommand
    from .search.search_command import SearchCommand

    return [SearchCommand, ReconstructCommand]
