"""Similarity search after Krüger et al. 2010: end-effector and PCA feature sets, kNN indexes
(kd-tree, sharded, HNSW), the lazy neighbourhood graph, subsequence DTW, logical search,
reconstruction and the fat-graph base poses. :mod:`.plugin` registers them."""
