"""Pose features (end effectors, PCA), pose distance measures and the kNN indexes
(kd-tree, sharded, HNSW) with the nearest-poses analysis."""
