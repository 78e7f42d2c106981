"""Global search: the certified subsequence DTW (the default, ``matchers.search``), plain
subsequence DTW, the lazy neighbourhood graph, logical search, their kernels, the
``mocapflow search`` command and its server."""
