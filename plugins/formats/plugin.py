"""Registration of the built-in file formats (the ``formats`` package): readers and writers
``amc`` (Acclaim ASF/AMC), ``bvh``, ``fbx`` (reader), ``gltf`` (``.gltf``/``.glb``), ``c3d`` and ``trc`` (markers), and the ingest steps that
use them (``formats.load``, ``formats.load_markers``, ``formats.library``, ``formats.export``), and the skeleton
naming dialects of :mod:`.joint_maps`, and the ``mocapflow export`` and ``mocapflow index`` commands.
numba kernels are imported only when a file is read."""

from __future__ import annotations

from typing import Any

from mocapflow.framework.plugins import hookimpl


@hookimpl
def register_formats() -> list[type]:
    from .asf_amc import AmcFormat, AsfFormat
    from .bvh import BvhFormat
    from .c3d import C3dFormat
    from .fbx import FbxFormat
    from .gltf import GltfFormat
    from .library import LoadLibrary
    from .steps import ExportMotions, LoadMarkers, LoadMotions
    from .trc import TrcFormat

    return [
        AmcFormat,
        AsfFormat,
        BvhFormat,
        C3dFormat,
        FbxFormat,
        GltfFormat,
        TrcFormat,
        LoadMotions,
        LoadMarkers,
        LoadLibrary,
        ExportMotions,
    ]


@hookimpl
def register_joint_maps() -> list[Any]:
    from .joint_maps import JOINT_MAPS

    return list(JOINT_MAPS)


@hookimpl
def register_commands() -> list[type]:
    from .export_command import ExportCommand
    from .index_command import IndexCommand

    return [ExportCommand, IndexCommand]
