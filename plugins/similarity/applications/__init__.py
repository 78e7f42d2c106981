"""What is built on the kNN search: reconstruction from sparse markers (and its
evaluation), fat-graph base poses, the distance-measure correlation study."""
