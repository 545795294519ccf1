"""Benchmark family "stereo": the semi-global matching pipeline of kernels.stereo.

Case `stereo.sgm`, at (height, width, disparities) = (256, 256, 64), (500, 741, 64) (Middlebury 2014
quarter size) and (375, 1242, 128) (KITTI's size); quick mode runs the first two, tiny mode runs
(64, 128, 32), well under a second with every phase, for the test suite. A random texture and its
copy shifted by 5 pixels plus noise (timings do not depend on the content), float32 in [0, 1]:

  * cost_s: census cost volume, 7x9 window (62 bits), transforms included, as uint8 (compact mode,
    the form the default pipeline uses);
  * aggregate_s: SGM over 8 paths (P1 = 8, P2 = 64) of that volume (kernels.stereo.sgm: on the CPU
    the two-sweep scheme of kernels.stereo.sweep, int16 lanes, a uint16 aggregate);
  * backend_s: SGM-8, both views' winners and the left-right check on that volume in one call
    (kernels.stereo.sgm_disparity), the pipeline's back end;
  * total_s: the default pipeline, research.stereo.matching.match with StereoConfig() (census 7x9 +
    SGM-8 + winner-take-all with the sub-pixel parabola + the right view's winner + the left-right
    check), from the images to the disparity and validity maps on the host;
  * peak_mb: drlab's largest live arrays during total_s, from their nbytes (not RSS; tracemalloc
    does not see Warp's allocations; research.stereo.matching.peak_volume_bytes): the uint8 cost volume and
    the uint16 aggregate (3 bytes per cell; plus padded copies when D is not a multiple of 32). No
    volume per path exists: each SGM sweep keeps two rows of L_r per path.

With `compare=True` and OpenCV importable, each case also times cv2.StereoSGBM 3-way on the same
texture as 8-bit grey (blockSize 3, P1 = 8*3*3^2, P2 = 32*3*3^2, uniquenessRatio 10, speckle window
100 and range 32, disp12MaxDiff 1, preFilterCap 63), interleaved with drlab's phases in one
`time_medians` call: keys `ref`, `ref_total_s` and `speedup_total` (OpenCV's time / drlab's,
> 1 means drlab is faster); without OpenCV the case has `ref_missing` instead.

Case `stereo.default`, at 256x256x64 and 741x500x64 (tiny mode: 64x128x32), on the same pair and with
the same StereoSGBM reference: research.stereo.matching's DEFAULT_CONFIG, the pipeline `match` runs when no
configuration is given ("adcensus": census 7x9 + BT on the clipped x-Sobel gradient + 0.3 x intensity
BT, kernels.stereo.adcensus; SGM-8; both views' winners, the left-right check, border invalidation and
a 3x3 median). The `stereo.sgm` cases above time StereoConfig()'s field defaults (census + SGM-8),
which are not that pipeline:

  * cost_s: research.stereo.matching.cost_volume with DEFAULT_CONFIG (float32 below its float budget, as
    `match` runs it at these sizes: `compact` says which), images to the volume;
  * aggregate_s: SGM-8 of that volume with the configuration's penalties (kernels.stereo.sgm; in compact
    mode the int16 two-sweep SGM of kernels.stereo.sweep, penalties in the volume's units);
  * backend_s: research.stereo.matching.disparity_from_cost, everything after the cost (SGM, both winners, the
    left-right check, the post-processing, the maps on the host);
  * total_s: research.stereo.matching.match with DEFAULT_CONFIG; `speedup_total` against StereoSGBM as above;
  * total_fast_s: research.stereo.matching.match with FAST_DEFAULT_CONFIG, the same pipeline in compact mode at every
    size (uint8 costs by the vector rho of kernels.stereo.adcensus, the int16 SGM); `speedup_total_fast`;
  * peak_mb: research.stereo.matching.peak_volume_bytes (the cost volume and SGM's aggregate; the adcensus
    kernel's band buffers are not counted).

Case `stereo.memory` (full mode only; tiny mode runs it at the tiny size): the default pipeline once
at Middlebury 2014's half size, 1482x994 with 256 disparities, in compact mode (uint8 costs, a
uint16 aggregate; float32 volumes would take 3.0 GiB): `peak_mb` (the volumes' nbytes, 1079 MiB
here), `rss_peak_mb` (the process's peak resident set after the run, ru_maxrss, which includes
everything the process held before), `compact` and `total_once_s` (one run, not a median).

Profile (where the time goes): CPU time of one thread (DRLAB_THREADS=1, cv2.setNumThreads(1),
time.process_time, median of 5, a loaded host), 256x256x64 / 741x500x64: census transform 2.6 /
12.6 ms per image, census cost volume (both transforms + Hamming distances) 9.0 / 47 ms, SGM-8
sweeps 11.5 / 84 ms, SGM + both winners + LR check 14.0 / 96 ms, the whole default pipeline 23.5 /
145 ms against OpenCV StereoSGBM 3-way's 6.0 / 39 ms (3.9x / 3.7x). Per-call Python overhead and
input checks are below 1 ms. The stereo.default pipeline in the committed table
(results/performance/table.md: 2 threads, wall): 75.5 / 351 ms against StereoSGBM's 6.07 / 38.4 ms.

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
from research.bench import SETTLE_S, time_medians

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


def _head(case: str, device: str, threads: int, height: int, width: int, disparities: int) -> dict[str, Any]:
    """The keys every stereo row starts with: its case, where it ran, and the size of its problem."""
    return {"bench": f"stereo.{case}", "device": str(wp.get_device(device)), "threads": threads, "height": height,
            "width": width, "disparities": disparities}


def cases(device: str = "cpu", quick: bool = False, tiny: bool = False, compare: bool = False) -> Iterator[dict]:
    from research.stereo.matching import StereoConfig, match, peak_volume_bytes

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
            return stereo.census_cost(left, right, 0, disparities, *CENSUS_RADII, compact=True, device=device)

        volume = cost()

        def aggregate():
            return stereo.sgm(volume, P1, P2, paths=PATHS, device=device)

        def backend():
            return stereo.sgm_disparity(volume, 0, P1, P2, PATHS, device=device)

        def total():
            return match(left_np, right_np, 0, disparities, cfg, device)

        fns = {"cost": cost, "aggregate": aggregate, "backend": backend, "total": total}
        row: dict[str, Any] = {}
        _reference(fns, row, cv2, compare, disparities, left_np, right_np)
        t = time_medians(fns, sync=lambda: wp.synchronize_device(device), settle_s=SETTLE_S)
        yield {
            **_head("sgm", device, threads, height, width, disparities),
            "paths": PATHS,
            "cost": f"census{2 * CENSUS_RADII[0] + 1}x{2 * CENSUS_RADII[1] + 1}",
            "cost_s": t["cost"],
            "aggregate_s": t["aggregate"],
            "backend_s": t["backend"],
            "total_s": t["total"],
            "peak_mb": peak_volume_bytes(cfg, height, width, disparities) / 2**20,
            **row,
            **({"ref_total_s": t["ref_total"], "speedup_total": t["ref_total"] / t["total"]}
               if "ref_total" in t else {}),
        }
        del volume
    for height, width, disparities in TINY_SIZES if tiny else DEFAULT_SIZES:
        yield _default_case(device, threads, height, width, disparities, cv2 if compare else None, compare)
    if quick and not tiny:
        return
    yield _memory_case(device, threads, *(TINY_SIZES[0] if tiny else MEMORY_SIZE))


DEFAULT_SIZES = SIZES[:2]  # the sizes of the "default pipeline <= 5x StereoSGBM" target


def _reference(fns: dict, row: dict, cv2: Any, compare: bool, disparities: int, left: np.ndarray,
               right: np.ndarray) -> None:
    """Add OpenCV StereoSGBM's `ref_total` to `fns` and its description to `row` (or `ref_missing`)."""
    if compare and cv2 is not None:
        sgbm = _sgbm(disparities)
        l8, r8 = (np.floor(x * 255.0 + 0.5).astype(np.uint8) for x in (left, right))
        fns["ref_total"] = lambda: sgbm.compute(l8, r8)
        row["ref"] = (f"OpenCV {cv2.__version__} cv2.StereoSGBM 3-way (blockSize {SGBM_BLOCK}, P1 8*3*bs^2, "
                      f"P2 32*3*bs^2, uniqueness 10, speckle 100/32), {cv2.getNumThreads()} threads")
    elif compare:
        row["ref_missing"] = "cv2 (opencv-python-headless)"


def _default_case(device: str, threads: int, height: int, width: int, disparities: int, cv2: Any,
                  compare: bool) -> dict:
    """Case `stereo.default`: research.stereo.matching.DEFAULT_CONFIG's pipeline (module docstring)."""
    from research.stereo.matching import (DEFAULT_CONFIG, FAST_DEFAULT_CONFIG, compact_penalties, cost_volume,
                                 disparity_from_cost, match, peak_volume_bytes, uses_compact)

    cfg = DEFAULT_CONFIG
    left_np, right_np = _pair(height, width)
    compact = uses_compact(cfg, height, width, disparities)
    p1, p2 = compact_penalties(cfg) if compact else (cfg.p1, cfg.p2)
    paths = int(cfg.aggregation[3:])

    def cost():
        return cost_volume(left_np, right_np, 0, disparities, cfg, device)

    volume = cost()
    fns = {"cost": cost,
           "aggregate": lambda: stereo.sgm(volume, float(p1), float(p2), paths=paths, device=device),
           "backend": lambda: disparity_from_cost(volume, 0, cfg, device),
           "total": lambda: match(left_np, right_np, 0, disparities, cfg, device),
           "total_fast": lambda: match(left_np, right_np, 0, disparities, FAST_DEFAULT_CONFIG, device)}
    row: dict[str, Any] = {}
    _reference(fns, row, cv2, compare, disparities, left_np, right_np)
    t = time_medians(fns, sync=lambda: wp.synchronize_device(device), settle_s=SETTLE_S)
    del volume
    return {
        **_head("default", device, threads, height, width, disparities),
        "paths": paths,
        "config": cfg.label,
        "compact": compact,
        "cost_s": t["cost"],
        "aggregate_s": t["aggregate"],
        "backend_s": t["backend"],
        "total_s": t["total"],
        "total_fast_s": t["total_fast"],
        "peak_mb": peak_volume_bytes(cfg, height, width, disparities) / 2**20,
        **row,
        **({"ref_total_s": t["ref_total"], "speedup_total": t["ref_total"] / t["total"],
            "ref_total_fast_s": t["ref_total"], "speedup_total_fast": t["ref_total"] / t["total_fast"]}
           if "ref_total" in t else {}),
    }


MEMORY_SIZE = (994, 1482, 256)  # Middlebury 2014 at half resolution


def _memory_case(device: str, threads: int, height: int, width: int, disparities: int) -> dict:
    import resource
    import time

    from research.stereo.matching import StereoConfig, match, peak_volume_bytes, uses_compact

    left, right = _pair(height, width)
    cfg = StereoConfig()
    t0 = time.perf_counter()
    match(left, right, 0, disparities, cfg, device)
    seconds = time.perf_counter() - t0
    return {
        **_head("memory", device, threads, height, width, disparities),
        "compact": uses_compact(cfg, height, width, disparities),
        "peak_mb": peak_volume_bytes(cfg, height, width, disparities) / 2**20,
        "rss_peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,  # KiB on Linux
        "total_once_s": seconds,
    }
