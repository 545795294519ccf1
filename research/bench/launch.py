"""Benchmark family "launch": kernels.launch.launch_split against one plain launch.

Case `launch.split`: a compute-bound, race-free kernel. Thread i iterates

    x_{k+1} = sin(x_k) * 0.9 + cos(1.1 * x_k) * 0.5,   x_0 = input[i],

`ITERS` times in float64 and writes x_ITERS to out[i] alone. It is timed as one
launch (`single_s`) and split over `default_threads()` threads (DRLAB_THREADS,
else os.cpu_count()) (`split_s`), interleaved, the median of REPEATS runs each;
the two results must agree bit for bit. Sizes give ~0.7 s single-threaded on
the project's CPU (~0.12 s with quick; tiny, for the tests, a few milliseconds).
"""

from __future__ import annotations

import typing
from typing import Iterator

import numpy as np
import warp as wp

from kernels._arrays import declare_float_overloads
from kernels.launch import default_threads, launch_split
from research.bench import time_medians

ITERS = 256
ELEMENTS = 98_304
QUICK_ELEMENTS = 16_384
TINY_ELEMENTS = 1_024
# Per-run times on the project's VMs drift by ~15% even pinned to one core; 5 interleaved runs steady the ratio.
REPEATS = 5


@wp.kernel
def recurrence(x0: wp.array(dtype=typing.Any), out: wp.array(dtype=typing.Any), iters: int, offset: int):
    i = wp.tid() + offset
    x = x0[i]
    for _k in range(iters):
        x = wp.sin(x) * x0.dtype(0.9) + wp.cos(x * x0.dtype(1.1)) * x0.dtype(0.5)
    out[i] = x


declare_float_overloads(recurrence)  # concrete overloads: the module compiles ahead of time too (kernels.cuda_build)


def cases(device: str = "cpu", quick: bool = False, tiny: bool = False) -> Iterator[dict]:
    """The case `launch.split` (module docstring); `tiny`: the same case at a size that runs in milliseconds."""
    n = TINY_ELEMENTS if tiny else QUICK_ELEMENTS if quick else ELEMENTS
    threads = 1 if wp.get_device(device).is_cuda else default_threads()
    x0 = wp.array(np.random.default_rng(0).uniform(-2.0, 2.0, n), dtype=wp.float64, device=device)
    single = wp.zeros(n, dtype=wp.float64, device=device)
    split = wp.zeros(n, dtype=wp.float64, device=device)
    sync = lambda: wp.synchronize_device(device)  # noqa: E731

    t = time_medians(
        {
            "single": lambda: launch_split(recurrence, n, [x0, single, ITERS], device=device, threads=1),
            "split": lambda: launch_split(recurrence, n, [x0, split, ITERS], device=device, threads=threads),
        },
        repeats=REPEATS,
        sync=sync,
    )
    single_s, split_s = t["single"], t["split"]
    if not np.array_equal(single.numpy(), split.numpy()):
        raise RuntimeError("launch.split: the split launch differs from the single launch")
    yield {
        "bench": "launch.split",
        "device": str(wp.get_device(device)),
        "threads": threads,
        "elements": n,
        "iters": ITERS,
        "single_s": single_s,
        "split_s": split_s,
        "speedup": single_s / split_s,
    }
