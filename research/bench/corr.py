"""Benchmark family "corr": RAFT's correlation volume and lookups (kernels.corr).

All cases at RAFT's 1/8-resolution feature size for a 368x496 frame: height 46,
width 62, channels 256, levels 4, radius 4, float32, random features and
coordinates within +-8 px of each pixel's centre.

* `corr.build`: `build_s`, the all-pairs volume (1) plus its 4-level pyramid (2);
* `corr.lookup`: `fwd_s`, one dense lookup (4); `fwd_bwd_s`, the lookup plus its
  adjoint to every pyramid level and to the coordinates; `bytes`, the stored pyramid;
* `corr.lookup_onthefly`: `fwd_s` and `fwd_bwd_s` of the on-the-fly lookup (the
  backward reaching f1, every pooled f2 level and the coordinates); `bytes`, what it
  holds instead of the pyramid (f1, the pooled f2 pyramid, one patch buffer), and
  `max_abs_diff`, its largest deviation from the dense lookup.

Targets on 2 cores: one dense lookup within 0.05 s, the build within 0.4 s.
`tiny=True` runs every case at 12 x 16 features, 16 channels, 3 levels, radius 2
(same keys and phases, about a second in all) for the test suite.
"""

from __future__ import annotations

import os
from typing import Iterator

import numpy as np
import warp as wp

from kernels import corr
from research.bench import time_median

FULL = dict(height=46, width=62, channels=256, levels=4, radius=4)
TINY = dict(height=12, width=16, channels=16, levels=3, radius=2)


def cases(device: str = "cpu", quick: bool = False, tiny: bool = False) -> Iterator[dict]:
    dev = wp.get_device(device)
    threads = 1 if dev.is_cuda else (os.cpu_count() or 1)
    repeats = 3 if quick or tiny else 5
    sync = lambda: wp.synchronize_device(dev)  # noqa: E731
    sizes = TINY if tiny else FULL
    height, width, levels, radius = sizes["height"], sizes["width"], sizes["levels"], sizes["radius"]
    rng = np.random.default_rng(0)
    shape = (sizes["channels"], height, width)
    f1 = wp.array(rng.standard_normal(shape).astype(np.float32), device=dev)
    f2 = wp.array(rng.standard_normal(shape).astype(np.float32), device=dev)
    centres = np.stack(np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5))
    coords = wp.array((centres + rng.uniform(-8, 8, (2, height, width))).astype(np.float32), device=dev)
    grad_out = wp.array(rng.standard_normal((levels * (2 * radius + 1) ** 2, height, width)).astype(np.float32),
                        device=dev)
    head = {"device": str(dev), "threads": threads, **sizes}

    def build() -> list:
        return corr.correlation_pyramid(corr.correlation_volume(f1, f2), levels)

    yield {"bench": "corr.build", **head, "build_s": time_median(build, repeats=repeats, sync=sync)}

    pyramid = build()
    dense_fwd = lambda: corr.lookup(pyramid, coords, radius)  # noqa: E731

    def dense_fwd_bwd() -> None:
        corr.lookup(pyramid, coords, radius)
        corr.lookup_backward(pyramid, coords, radius, grad_out)

    yield {"bench": "corr.lookup", **head, "fwd_s": time_median(dense_fwd, repeats=repeats, sync=sync),
           "fwd_bwd_s": time_median(dense_fwd_bwd, repeats=repeats, sync=sync),
           "bytes": corr.dense_bytes(height, width, levels)}

    f2_pyramid = corr.pool_features(f2, levels)
    otf_fwd = lambda: corr.lookup_onthefly(f1, f2_pyramid, coords, radius)  # noqa: E731

    def otf_fwd_bwd() -> None:
        corr.lookup_onthefly(f1, f2_pyramid, coords, radius)
        corr.lookup_onthefly_backward(f1, f2_pyramid, coords, radius, grad_out)

    diff = float(np.abs(otf_fwd().numpy() - dense_fwd().numpy()).max())
    yield {"bench": "corr.lookup_onthefly", **head, "fwd_s": time_median(otf_fwd, repeats=repeats, sync=sync),
           "fwd_bwd_s": time_median(otf_fwd_bwd, repeats=repeats, sync=sync),
           "bytes": corr.onthefly_bytes(height, width, sizes["channels"], levels, radius), "max_abs_diff": diff}
