"""drlab compute kernels (NVIDIA Warp): pure compute, no file I/O.

Each family is one module (volume, splat, stereo, corr, flow) opening with the
math it implements. `kernels.launch` holds the race-free split launcher for
CPU kernels. This package never imports `research`.
"""
