"""Benchmark family "stereo": the semi-global matching pipeline of kernels.stereo.

Case `stereo.sgm`, at (height, width, disparities) = (256, 256, 64) and
(375, 1242, 128) (KITTI's size; quick mode runs the first only; tiny mode runs
(64, 128, 32), well under a second with every phase, for the test suite). A random
texture and its copy shifted by 5 pixels plus noise (timings do not depend on
the content), float32:

  * cost_s: census cost volume, 7x9 window (62 bits), transforms included;
  * aggregate_s: SGM over 8 paths (P1 = 8, P2 = 64) of that volume;
  * total_s: cost + SGM-8 + winner-take-all with the sub-pixel parabola.

Each is the median of 3 interleaved runs after a warm-up (research.bench).
Every call allocates its output volume, as the entry points do, so page-fault
time for fresh memory is part of each phase.
"""

from __future__ import annotations

from typing import Iterator

import numpy as np
import warp as wp

from kernels import stereo
from kernels.launch import default_threads
from research.bench import time_medians

SIZES = ((256, 256, 64), (375, 1242, 128))
TINY_SIZES = ((64, 128, 32),)
CENSUS_RADII = (3, 4)
P1, P2 = 8.0, 64.0
PATHS = 8
SHIFT = 5


def _pair(height: int, width: int, device: str) -> tuple[wp.array, wp.array]:
    rng = np.random.default_rng(0)
    left = rng.uniform(0.0, 1.0, (height, width)).astype(np.float32)
    right = np.roll(left, -SHIFT, axis=1) + rng.normal(0.0, 0.02, (height, width)).astype(np.float32)
    return wp.array(left, device=device), wp.array(right, device=device)


def cases(device: str = "cpu", quick: bool = False, tiny: bool = False) -> Iterator[dict]:
    dev = wp.get_device(device)
    threads = 1 if dev.is_cuda else default_threads()
    for height, width, disparities in TINY_SIZES if tiny else (SIZES[:1] if quick else SIZES):
        left, right = _pair(height, width, device)

        def cost():
            return stereo.census_cost(left, right, 0, disparities, *CENSUS_RADII, device=device)

        volume = cost()

        def aggregate():
            return stereo.sgm(volume, P1, P2, paths=PATHS, device=device)

        def total():
            return stereo.wta(stereo.sgm(cost(), P1, P2, paths=PATHS, device=device), 0, device=device)

        t = time_medians({"cost": cost, "aggregate": aggregate, "total": total},
                         sync=lambda: wp.synchronize_device(device))
        yield {
            "bench": "stereo.sgm",
            "device": str(dev),
            "threads": threads,
            "height": height,
            "width": width,
            "disparities": disparities,
            "paths": PATHS,
            "cost": f"census{2 * CENSUS_RADII[0] + 1}x{2 * CENSUS_RADII[1] + 1}",
            "cost_s": t["cost"],
            "aggregate_s": t["aggregate"],
            "total_s": t["total"],
        }
        del volume
