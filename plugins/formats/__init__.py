"""Built-in file formats (readers, writers) as one plugin.

Readers: ``amc`` (Acclaim ASF/AMC), ``bvh``, ``c3d`` and ``trc`` (markers). Module-level
functions (``read_amc``, ``read_bvh``...) live in the format modules; numba kernels are
imported only when a file is read.
"""
from __future__ import annotations

from mocapflow.framework.plugins import hookimpl


@hookimpl
def register_formats() -> list[type]:
    from .asf_amc import AmcFormat
    from .bvh import BvhFormat
    from .c3d import C3dFormat
    from .trc import TrcFormat

    return [AmcFormat, BvhFormat, C3dFormat, TrcFormat]
