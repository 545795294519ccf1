"""Optical flow on top of kernels.corr (and kernels.lucas_kanade): estimators, benchmark protocols, test pairs.

    raft.py            weight-free RAFT-style flow (CorrFlow): fixed multi-scale patch features, windowed
                       correlation lookups, the update; EPE / F1 of one pair, the Middlebury colour wheel
    coarse_to_fine.py  coarse-to-fine correlation flow (C2F): normalised-patch lookups with warping and a
                       TV-L1 step
    metrics.py         the benchmarks' evaluation protocols: Sintel, KITTI flow and Middlebury flow
    texture.py         real-texture pairs: a photograph warped by a known smooth flow
"""
