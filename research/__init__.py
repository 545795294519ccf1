"""drlab research layer: everything built on the Warp kernels.

Cameras, image I/O, Mitsuba ground-truth datasets, gradient checks, benchmarks,
models, metrics and the `drlab` CLI. Imports run one way only:
experiments -> research -> kernels.
"""

__version__ = "0.1.0"
