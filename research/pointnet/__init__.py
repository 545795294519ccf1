"""Point-cloud classification: synthetic shape clouds (shapes), PointNet and PointNet++ on the Warp kernels
(model, train), and a non-learned D2 + PCA nearest-neighbour baseline (baseline)."""
