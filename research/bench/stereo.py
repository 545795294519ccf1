"""Benchmark family "stereo": the semi-global matching pipeline of kernels.stereo.

Case `stereo.sgm`, at (height, width, disparities) = (256, 256, 64), (500, 741, 64) (Middlebury 2014
quarter size) and (375, 1242, 128) (KITTI's size); quick mode runs the first two, tiny mode runs
(64, 128, 32), well under a second with every phase, for the test suite. A random texture and its
copy shifted by 5 pixels plus noise (timings do not depend on the content), float32 in [0, 1]:

  * cost_s: census cost volume, 7x9 window (62 bits), transforms included;
  * aggregate_s: SGM over 8 paths (P1 = 8, P2 = 64) of that volume;
  * total_s: the default pipeline, research.stereo.match with StereoConfig() (census 7x9 +
    SGM-8 + winner-take-all with the sub-pixel parabola + the right view's winner + the left-right
    check), from the images to the disparity and validity maps on the host;
  * peak_mb: drlab's largest live arrays during total_s, from their nbytes (not RSS; tracemalloc
    does not see Warp's allocations; research.stereo.peak_volume_bytes): the cost volume and SGM's
    aggregate (plus its padded copies when D is not a multiple of 8), each H x W x D float32.

With `compare=True` and OpenCV importable, each case also times cv2.StereoSGBM 3-way on the same
texture as 8-bit grey (blockSize 3, P1 = 8*3*3^2, P2 = 32*3*3^2, uniquenessRatio 10, speckle window
100 and range 32, disp12MaxDiff 1, preFilterCap 63), interleaved with drlab's phases in one
`time_medians` call: keys `ref`, `ref_total_s` and `speedup_total` (OpenCV's time / drlab's,
> 1 means drlab is faster); without OpenCV the case has `ref_missing` instead.

Case `stereo.memory` (full mode only; tiny mode runs it at the tiny size): the default pipeline once
at Middlebury 2014's half size, 1482x994 with 256 disparities, where float32 volumes would take
3.0 GiB and research.stereo switches census + SGM to compact mode (uint8 costs, uint16 aggregate):
`peak_mb` (the volumes' nbytes), `rss_peak_mb` (the process's peak resident set after the run,
ru_maxrss, which includes everything the process held before), `compact` and `total_once_s` (one
run, not a median: it takes tens of seconds).

Profile (where the time goes), CPU time of one thread (DRLAB_THREADS=1, cv2.setNumThreads(1),
time.process_time, median of 5; the shared host's wall times were too noisy to compare), at
256x256x64 before this session's changes / after them: census transform 9.0 ms per image (two per
pair), census cost 15 / 9 ms, SGM-8 47 / 40 ms, WTA 7.6 ms + right-view WTA 17.5 ms / both in one row
pass 19-22 ms, LR check 1 ms; the whole default pipeline 113 / 98 ms against OpenCV StereoSGBM 3-way's
5.9-6.5 ms (15-17x; at 741x500x64, 664 / 546 ms against 39-41 ms, 14x). Per-call Python overhead
and input checks are below 1 ms. What stops the 5x target: SGM-8 alone is 6x SGBM's whole run.
It makes 8 passes of float32 8-lane vectors over the volume (four axes, each reading the cost and
reading and writing the aggregate), where SGBM's 3-way mode runs 16-lane int16 arithmetic in fewer
passes. Warp's CPU code turns 8-wide float32 vectors into SIMD instructions, but not uint16 ones: an
8 x uint16 SGM was 2x slower than float32, and the compact mode's conversions make SGM 1.8x slower, so
compact mode is kept for memory. Closing the gap needs SGBM's single-pass scanline scheme with
16-bit lanes, which Warp's CPU code generation does not give today.

Each figure is the median of 3 interleaved runs after a warm-up (research.bench). Every call
allocates its output volume, as the entry points do, so page-fault time for fresh memory is part
of each phase.
"""

from __future__ import annotations

from typing import Any, Iterator

import numpy as np
import warp as wp

from kernels import stereo
from kernels.launch import default_threads
from research.bench import time_medians

SIZES = ((256, 256, 64), (500, 741, 64), (375, 1242, 128))
QUICK_SIZES = SIZES[:2]
TINY_SIZES = ((64, 128, 32),)
CENSUS_RADII = (3, 4)
P1, P2 = 8.0, 64.0
PATHS = 8
SHIFT = 5
SGBM_BLOCK = 3


def _pair(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    left = rng.uniform(0.0, 1.0, (height, width)).astype(np.float32)
    right = np.roll(left, -SHIFT, axis=1) + rng.normal(0.0, 0.02, (height, width)).astype(np.float32)
    return left, np.clip(right, 0.0, 1.0).astype(np.float32)


def _sgbm(disparities: int) -> Any:
    import cv2

    b = SGBM_BLOCK
    return cv2.StereoSGBM_create(minDisparity=0, numDisparities=disparities, blockSize=b, P1=8 * 3 * b * b,
                                 P2=32 * 3 * b * b, disp12MaxDiff=1, preFilterCap=63, uniquenessRatio=10,
                                 speckleWindowSize=100, speckleRange=32, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)


def cases(device: str = "cpu", quick: bool = False, tiny: bool = False, compare: bool = False) -> Iterator[dict]:
    from research.stereo import StereoConfig, match, peak_volume_bytes

    dev = wp.get_device(device)
    threads = 1 if dev.is_cuda else default_threads()
    cv2 = None
    if compare:
        try:
            import cv2
        except ImportError:
            cv2 = None
    for height, width, disparities in TINY_SIZES if tiny else (QUICK_SIZES if quick else SIZES):
        left_np, right_np = _pair(height, width)
        left, right = wp.array(left_np, device=device), wp.array(right_np, device=device)
        cfg = StereoConfig()

        def cost():
            return stereo.census_cost(left, right, 0, disparities, *CENSUS_RADII, device=device)

        volume = cost()

        def aggregate():
            return stereo.sgm(volume, P1, P2, paths=PATHS, device=device)

        def total():
            return match(left_np, right_np, 0, disparities, cfg, device)

        fns = {"cost": cost, "aggregate": aggregate, "total": total}
        row: dict[str, Any] = {}
        if compare and cv2 is not None:
            sgbm = _sgbm(disparities)
            l8, r8 = (np.floor(x * 255.0 + 0.5).astype(np.uint8) for x in (left_np, right_np))
            fns["ref_total"] = lambda: sgbm.compute(l8, r8)
            row["ref"] = (f"OpenCV {cv2.__version__} cv2.StereoSGBM 3-way (blockSize {SGBM_BLOCK}, P1 8*3*bs^2, "
                          f"P2 32*3*bs^2, uniqueness 10, speckle 100/32), {cv2.getNumThreads()} threads")
        elif compare:
            row["ref_missing"] = "cv2 (opencv-python-headless)"
        t = time_medians(fns, sync=lambda: wp.synchronize_device(device))
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
            "peak_mb": peak_volume_bytes(cfg, height, width, disparities) / 2**20,
            **row,
            **({"ref_total_s": t["ref_total"], "speedup_total": t["ref_total"] / t["total"]}
               if "ref_total" in t else {}),
        }
        del volume
    if quick and not tiny:
        return
    yield _memory_case(device, threads, *(TINY_SIZES[0] if tiny else MEMORY_SIZE))


MEMORY_SIZE = (994, 1482, 256)  # Middlebury 2014 at half resolution


def _memory_case(device: str, threads: int, height: int, width: int, disparities: int) -> dict:
    import resource
    import time

    from research.stereo import StereoConfig, match, peak_volume_bytes, uses_compact

    left, right = _pair(height, width)
    cfg = StereoConfig()
    t0 = time.perf_counter()
    match(left, right, 0, disparities, cfg, device)
    seconds = time.perf_counter() - t0
    return {
        "bench": "stereo.memory",
        "device": str(wp.get_device(device)),
        "threads": threads,
        "height": height,
        "width": width,
        "disparities": disparities,
        "compact": uses_compact(cfg, height, width, disparities),
        "peak_mb": peak_volume_bytes(cfg, height, width, disparities) / 2**20,
        "rss_peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,  # KiB on Linux
        "total_once_s": seconds,
    }
