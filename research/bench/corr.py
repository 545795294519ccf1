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

Issue targets on 2 cores: one dense lookup within 0.05 s, the build within 0.4 s.
"""

from __future__ import annotations

import os
from typing import Iterator

import numpy as np
import warp as wp

from kernels import corr
from research.bench import time_median

HEIGHT, WIDTH, CHANNELS, LEVELS, RADIUS = 46, 62, 256, 4, 4


def cases(device: str = "cpu", quick: bool = False) -> Iterator[dict]:
    dev = wp.get_device(device)
    threads = 1 if dev.is_cuda else (os.cpu_count() or 1)
    repeats = 3 if quick else 5
    sync = lambda: wp.synchronize_device(dev)  # noqa: E731
    rng = np.random.default_rng(0)
    shape = (CHANNELS, HEIGHT, WIDTH)
    f1 = wp.array(rng.standard_normal(shape).astype(np.float32), device=dev)
    f2 = wp.array(rng.standard_normal(shape).astype(np.float32), device=dev)
    centres = np.stack(np.meshgrid(np.arange(WIDTH) + 0.5, np.arange(HEIGHT) + 0.5))
    coords = wp.array((centres + rng.uniform(-8, 8, (2, HEIGHT, WIDTH))).astype(np.float32), device=dev)
    grad_out = wp.array(rng.standard_normal((LEVELS * (2 * RADIUS + 1) ** 2, HEIGHT, WIDTH)).astype(np.float32),
                        device=dev)
    sizes = {"height": HEIGHT, "width": WIDTH, "channels": CHANNELS, "levels": LEVELS, "radius": RADIUS}
    head = {"device": str(dev), "threads": threads, **sizes}

    def build() -> list:
        return corr.correlation_pyramid(corr.correlation_volume(f1, f2), LEVELS)

    yield {"bench": "corr.build", **head, "build_s": time_median(build, repeats=repeats, sync=sync)}

    pyramid = build()
    dense_fwd = lambda: corr.lookup(pyramid, coords, RADIUS)  # noqa: E731

    def dense_fwd_bwd() -> None:
        corr.lookup(pyramid, coords, RADIUS)
        corr.lookup_backward(pyramid, coords, RADIUS, grad_out)

    yield {"bench": "corr.lookup", **head, "fwd_s": time_median(dense_fwd, repeats=repeats, sync=sync),
           "fwd_bwd_s": time_median(dense_fwd_bwd, repeats=repeats, sync=sync),
           "bytes": corr.dense_bytes(HEIGHT, WIDTH, LEVELS)}

    f2_pyramid = corr.pool_features(f2, LEVELS)
    otf_fwd = lambda: corr.lookup_onthefly(f1, f2_pyramid, coords, RADIUS)  # noqa: E731

    def otf_fwd_bwd() -> None:
        corr.lookup_onthefly(f1, f2_pyramid, coords, RADIUS)
        corr.lookup_onthefly_backward(f1, f2_pyramid, coords, RADIUS, grad_out)

    diff = float(np.abs(otf_fwd().numpy() - dense_fwd().numpy()).max())
    yield {"bench": "corr.lookup_onthefly", **head, "fwd_s": time_median(otf_fwd, repeats=repeats, sync=sync),
           "fwd_bwd_s": time_median(otf_fwd_bwd, repeats=repeats, sync=sync),
           "bytes": corr.onthefly_bytes(HEIGHT, WIDTH, CHANNELS, LEVELS, RADIUS), "max_abs_diff": diff}
