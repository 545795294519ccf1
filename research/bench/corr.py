"""Benchmark family "corr": RAFT's correlation volume and lookups (kernels.corr).

All cases at RAFT's 1/8-resolution feature size for a 368x496 frame: height 46,
width 62, channels 256, levels 4, radius 4, float32, random features and
coordinates within +-8 px of each pixel's centre.

* `corr.build`: `build_s`, the all-pairs volume (1) plus its 4-level pyramid (2);
* `corr.lookup`: `fwd_s`, one dense lookup (4); `fwd_bwd_s`, the lookup plus its
  adjoint to every pyramid level and to the coordinates; `bytes`, the stored pyramid;
* `corr.lookup_onthefly`: `fwd_s` and `fwd_bwd_s` of the on-the-fly lookup (the
  backward reaching f1, every pooled f2 level and the coordinates); `max_abs_diff`, its
  largest deviation from the dense lookup; `ratio_to_dense_fwd`, its forward time over the
  dense lookup's (timed interleaved with it); `feature_dtype` "float32";
* `corr.lookup_onthefly_float16`: the same lookup from features stored in float16
  (`corr.onthefly_features`, stored once; `corr.lookup_onthefly_features` timed, which widens
  them per call; forward only, so no `fwd_bwd_s`), timed in the same interleaved call;
  `max_abs_diff` from the dense lookup, `max_abs_diff_float32` from the float32 on-the-fly
  lookup and `rel_diff_float32`, that over the largest |output| (the correlation's scale).

Memory, from the arrays' nbytes computed from their shapes (Warp's allocations are invisible to
tracemalloc), outputs excluded on both sides (the two lookups return the same array):
  * dense `bytes`: the volume pyramid, kept between lookups (`corr.dense_bytes`);
  * on-the-fly `bytes`: what it keeps between lookups instead, f1 and the pooled f2 pyramid
    (`corr.onthefly_held_bytes`; in float16, their store, `corr.stored_bytes`), and
    `memory_ratio` = dense bytes / that;
  * on-the-fly `peak_bytes`: that plus the working buffers of one forward call (channels-last
    copies, the patch buffer; `corr.onthefly_bytes`), and `memory_ratio_peak` = dense bytes / that;
  * `peak_mb`: each row's largest figure in MiB.
The dense pyramid grows as (H W)^2 and the on-the-fly buffers as C H W, so the ratios grow with
the frame: `memory_ratio_sintel` and `memory_ratio_peak_sintel` are the same ratios at RAFT's 1/8
resolution of a 1024x436 MPI-Sintel frame (54 x 128 features), from the same byte counts.

`compare=True` (research.bench's convention) times PyTorch on the same inputs, interleaved with
drlab in one `time_medians` call, with torch.set_num_threads set to drlab's thread count:
  * build: RAFT's CorrBlock, `torch.matmul` of the flattened features / sqrt(C), then
    `F.avg_pool2d(2, stride=2)` three times (`ref_build_s`, `speedup_build`);
  * lookup: RAFT's CorrBlock.__call__, one `F.grid_sample` (bilinear, zero padding,
    align_corners=True) per level over the (2r+1)^2 window, at drlab's sample positions
    (x / 2^l - 1/2 in RAFT's integer-centred level pixels), so both compute the same
    values (`ref_max_abs_diff`) (`ref_fwd_s`, `speedup_fwd`). The on-the-fly case is
    compared with the same grid_sample lookup (which needs the dense pyramid).
Without torch those keys are absent and `ref_missing` names it.

Targets on 2 cores: the build no slower than PyTorch's, the dense lookup at least 2x grid_sample,
the on-the-fly lookup within 3x of the dense one while holding at least 10x less memory.
`tiny=True` runs every case at 12 x 16 features, 16 channels, 3 levels, radius 2
(same keys and phases, about a second in all) for the test suite.
"""

from __future__ import annotations

import importlib.util
import os
from typing import Any, Callable, Iterator

import numpy as np
import warp as wp

from kernels import corr
from research.bench import SETTLE_S, time_medians

FULL = dict(height=46, width=62, channels=256, levels=4, radius=4)
TINY = dict(height=12, width=16, channels=16, levels=3, radius=2)
SINTEL_FEATURES = (54, 128)  # RAFT's 1/8-resolution features of a 1024x436 MPI-Sintel frame
REF_BUILD = "torch.matmul + torch.nn.functional.avg_pool2d (RAFT CorrBlock)"
REF_LOOKUP = "torch.nn.functional.grid_sample (RAFT CorrBlock.__call__)"


def _torch_reference(f1: np.ndarray, f2: np.ndarray, coords: np.ndarray, levels: int, radius: int,
                     threads: int) -> tuple[Callable[[], list], Callable[[list], Any]]:
    """PyTorch's build (returns the pyramid) and lookup (of a built pyramid), as RAFT's CorrBlock does them."""
    import torch
    import torch.nn.functional as F

    torch.set_num_threads(threads)
    channels, height, width = f1.shape
    t1 = torch.from_numpy(f1).reshape(channels, height * width)
    t2 = torch.from_numpy(f2).reshape(channels, height * width)
    side = 2 * radius + 1
    d = torch.linspace(-radius, radius, side)
    # RAFT's delta: stack(meshgrid(dy, dx)) added to (x, y), so the slow window index moves x.
    delta = torch.stack(torch.meshgrid(d, d, indexing="ij"), dim=-1).view(1, side, side, 2)
    xy = torch.from_numpy(np.ascontiguousarray(coords)).permute(1, 2, 0).reshape(height * width, 1, 1, 2)

    def build() -> list:
        vol = torch.matmul(t1.t(), t2).view(height * width, 1, height, width) / channels ** 0.5
        pyramid = [vol]
        for _ in range(1, levels):
            pyramid.append(F.avg_pool2d(pyramid[-1], 2, stride=2))
        return pyramid

    def lookup(pyramid: list) -> Any:
        out = []
        for lvl, v in enumerate(pyramid):
            hl, wl = v.shape[-2:]
            # drlab's level-l position (x / 2^l in centre-at-+0.5 coordinates) in RAFT's integer-centred pixels.
            pos = xy / 2 ** lvl - 0.5 + delta
            gx = 2 * pos[..., :1] / max(wl - 1, 1) - 1
            gy = 2 * pos[..., 1:] / max(hl - 1, 1) - 1
            s = F.grid_sample(v, torch.cat([gx, gy], dim=-1), align_corners=True)
            out.append(s.view(height, width, side * side))
        return torch.cat(out, dim=-1).permute(2, 0, 1)

    return build, lookup


def cases(device: str = "cpu", quick: bool = False, tiny: bool = False, compare: bool = False) -> Iterator[dict]:
    dev = wp.get_device(device)
    threads = 1 if dev.is_cuda else (os.cpu_count() or 1)
    repeats = 3 if quick or tiny else 5
    sync = lambda: wp.synchronize_device(dev)  # noqa: E731
    sizes = TINY if tiny else FULL
    height, width, levels, radius = sizes["height"], sizes["width"], sizes["levels"], sizes["radius"]
    rng = np.random.default_rng(0)
    shape = (sizes["channels"], height, width)
    f1_np = rng.standard_normal(shape).astype(np.float32)
    f2_np = rng.standard_normal(shape).astype(np.float32)
    f1 = wp.array(f1_np, device=dev)
    f2 = wp.array(f2_np, device=dev)
    centres = np.stack(np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5))
    coords_np = (centres + rng.uniform(-8, 8, (2, height, width))).astype(np.float32)
    coords = wp.array(coords_np, device=dev)
    grad_out = wp.array(rng.standard_normal((levels * (2 * radius + 1) ** 2, height, width)).astype(np.float32),
                        device=dev)
    head = {"device": str(dev), "threads": threads, **sizes}
    ref = None
    missing: dict[str, str] = {}
    if compare:
        if dev.is_cuda or importlib.util.find_spec("torch") is None:
            missing = {"ref_missing": "torch (CPU)" if not dev.is_cuda else "torch reference runs on the CPU only"}
        else:
            ref = _torch_reference(f1_np, f2_np, coords_np, levels, radius, threads)

    def build() -> list:
        return corr.correlation_pyramid(corr.correlation_volume(f1, f2), levels)

    fns = {"drlab": build}
    if ref is not None:
        fns["ref"] = ref[0]
    t = time_medians(fns, repeats=repeats, sync=sync, settle_s=SETTLE_S)
    row = {"bench": "corr.build", **head, "build_s": t["drlab"], **missing}
    if ref is not None:
        row.update(ref=REF_BUILD, ref_build_s=t["ref"], speedup_build=t["ref"] / t["drlab"])
    yield row

    pyramid = build()
    dense_bytes = corr.dense_bytes(height, width, levels)
    dense_fwd = lambda: corr.lookup(pyramid, coords, radius)  # noqa: E731

    def dense_fwd_bwd() -> None:
        corr.lookup(pyramid, coords, radius)
        corr.lookup_backward(pyramid, coords, radius, grad_out)

    f2_pyramid = corr.pool_features(f2, levels)
    otf_fwd = lambda: corr.lookup_onthefly(f1, f2_pyramid, coords, radius)  # noqa: E731
    features16 = corr.onthefly_features(f1, f2_pyramid, feature_dtype="float16")
    otf16_fwd = lambda: corr.lookup_onthefly_features(features16, coords, radius)  # noqa: E731

    def otf_fwd_bwd() -> None:
        corr.lookup_onthefly(f1, f2_pyramid, coords, radius)
        corr.lookup_onthefly_backward(f1, f2_pyramid, coords, radius, grad_out)

    fns = {"dense": dense_fwd, "otf": otf_fwd, "otf16": otf16_fwd}
    ref_row: dict[str, Any] = {}
    if ref is not None:
        t_pyramid = ref[0]()
        fns["ref"] = lambda: ref[1](t_pyramid)
        ref_row = {"ref": REF_LOOKUP, "ref_max_abs_diff": float(np.abs(ref[1](t_pyramid).numpy()
                                                                          - dense_fwd().numpy()).max())}
    t = time_medians(fns, repeats=repeats, sync=sync, settle_s=SETTLE_S)
    t_bwd = time_medians({"dense": dense_fwd_bwd, "otf": otf_fwd_bwd}, repeats=repeats, sync=sync)
    channels = sizes["channels"]
    sintel_dense = corr.dense_bytes(*SINTEL_FEATURES, levels)
    dense_out = dense_fwd().numpy()
    otf_out = otf_fwd().numpy()
    for name, key, dtype in (("corr.lookup", "dense", None), ("corr.lookup_onthefly", "otf", "float32"),
                             ("corr.lookup_onthefly_float16", "otf16", "float16")):
        if dtype is None:
            nbytes = peak = dense_bytes
        else:
            nbytes = corr.onthefly_held_bytes(height, width, channels, levels, feature_dtype=dtype)
            peak = corr.onthefly_bytes(height, width, channels, levels, radius, feature_dtype=dtype)
        bwd = {"fwd_bwd_s": t_bwd[key]} if key in t_bwd else {}  # the float16 path is forward-only
        row = {"bench": name, **head, "fwd_s": t[key], **bwd, "bytes": nbytes, "peak_mb": peak / 2 ** 20, **missing}
        if dtype is not None:
            out = otf_out if dtype == "float32" else otf16_fwd().numpy()
            held_sintel = corr.onthefly_held_bytes(*SINTEL_FEATURES, channels, levels, feature_dtype=dtype)
            peak_sintel = corr.onthefly_bytes(*SINTEL_FEATURES, channels, levels, radius, feature_dtype=dtype)
            row.update(feature_dtype=dtype, max_abs_diff=float(np.abs(out - dense_out).max()),
                       ratio_to_dense_fwd=t[key] / t["dense"], peak_bytes=peak,
                       memory_ratio=dense_bytes / nbytes, memory_ratio_peak=dense_bytes / peak,
                       memory_ratio_sintel=sintel_dense / held_sintel,
                       memory_ratio_peak_sintel=sintel_dense / peak_sintel)
            if dtype != "float32":
                diff = float(np.abs(out - otf_out).max())
                row.update(max_abs_diff_float32=diff, rel_diff_float32=diff / float(np.abs(otf_out).max()))
        if ref is not None:
            row.update(ref_row, ref_fwd_s=t["ref"], speedup_fwd=t["ref"] / t[key])
        yield row
