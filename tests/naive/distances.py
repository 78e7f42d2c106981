"""Slow references for the pose distance measures."""

from __future__ import annotations

import math

import numpy as np


def point_cloud_distance(a, b, steps=20000):
    """Grid search over the rotation about +y (translation: centroids), brute force."""
    best = math.inf
    ca = a - a.mean(0)
    cb = b - b.mean(0)
    for th in np.linspace(0, 2 * math.pi, steps, endpoint=False):
        c, s = math.cos(th), math.sin(th)
        r = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
        rb = cb @ r.T
        d = ((ca[:, [0, 2]] - rb[:, [0, 2]]) ** 2).sum() + ((a[:, 1] - b[:, 1]) ** 2).sum()
        best = min(best, d)
    return math.sqrt(best)
