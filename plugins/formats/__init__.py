"""Built-in file formats: Acclaim ASF/AMC, BVH, C3D and TRC readers and writers.

Module-level functions (``read_amc``, ``read_bvh``...) live in the format modules;
:mod:`.plugin` registers the format components.
"""
