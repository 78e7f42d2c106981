"""Slow, obviously correct reference implementations of every fast kernel.

One module per area (``naive.knn``, ``naive.dtw``, ``naive.relational``,
``naive.cleaning``...). Tests import them as ``from naive.dtw import ...`` (pytest puts
``tests/`` on ``sys.path``) and compare the fast kernels against them on small random
inputs and awkward cases.
"""
