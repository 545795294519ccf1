"""Stereo on top of kernels.stereo: the matching pipelines and their metrics, and the benchmark run.

    matching.py   cost volume -> aggregation (SGM) -> winner-take-all -> left-right check ->
                  post-processing (`match`), drlab's default configuration, the KITTI fill, the
                  disparity and depth metrics and the benchmarks' protocols
    benchmark.py  experiments.stereo_depth's run on a benchmark folder (Middlebury, KITTI, ETH3D):
                  drlab's configurations and OpenCV StereoSGBM, scored by each benchmark's protocol
"""
