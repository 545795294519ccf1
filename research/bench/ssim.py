"""Benchmark family "ssim": the SSIM value and gradient of the 3DGS loss (kernels/ssim.py).

Inputs: two float32 images (H, W, 3) uniform in [0, 1] (seeds 0 and 1), as wp.arrays on the device, so
no host copy is timed. Sizes (full / quick / tiny): H = W = 200 and 800 (a 1/4 and a full NeRF-synthetic
view) / 200 / 32. One row per size, `ssim.value_grad`:

  fwd_s              `ssim_map` and its mean (the value alone);
  fwd_bwd_s          `ssim`: the mean and its gradient with respect to x (what a training step needs);
  plain_fwd_bwd_s    the same call with the CPU fast paths off (kernels.fast_paths.disabled): the plain Warp
                     kernels, which are also the CUDA route; CPU only, timed in the same interleaved call;
  speedup_fast_path  plain_fwd_bwd_s / fwd_bwd_s (> 1: the fast path is faster);
  ref_fwd_bwd_s      with `compare` and PyTorch importable (the `[bench]` extra): the 3DGS training code's
                     SSIM (an 11x11 Gaussian `conv2d` per channel, zero padding 5, sigma 1.5) forward and
                     autograd backward on the same images, torch.set_num_threads = drlab's launch threads;
                     `speedup_fwd_bwd` = ref / drlab. CPU only; without torch `ref_missing` names it.

Every figure is research.bench.time_medians (median of REPEATS runs after a warm-up, interleaved).
"""

from __future__ import annotations

import importlib.util
from typing import Any, Callable, Iterator

import numpy as np
import warp as wp

from kernels import fast_paths, ssim as kssim
from kernels.launch import default_threads
from research.bench import SETTLE_S, time_medians

SIZES = {"full": (200, 800), "quick": (200,), "tiny": (32,)}
CHANNELS = 3
REPEATS = 5
REF = "torch.nn.functional.conv2d SSIM of the 3DGS training code, autograd backward"


def _torch_fwd_bwd(x: np.ndarray, y: np.ndarray, threads: int) -> Callable[[], Any]:
    """The 3DGS loss's SSIM in PyTorch (value and gradient w.r.t. x), on the same (H, W, C) images."""
    import torch
    import torch.nn.functional as F

    torch.set_num_threads(threads)
    c = x.shape[2]
    g = torch.from_numpy(kssim.gaussian_window().astype(np.float32))
    window = (g[:, None] @ g[None, :]).expand(c, 1, kssim.WINDOW, kssim.WINDOW).contiguous()
    xt = torch.from_numpy(np.ascontiguousarray(x.transpose(2, 0, 1)))[None].requires_grad_(True)
    yt = torch.from_numpy(np.ascontiguousarray(y.transpose(2, 0, 1)))[None]
    c1, c2 = kssim.K1 ** 2, kssim.K2 ** 2
    pad = kssim.WINDOW // 2

    def run() -> tuple[float, Any]:
        """The mean SSIM and its gradient w.r.t. x as a (1, C, H, W) tensor."""
        xt.grad = None
        mu_x = F.conv2d(xt, window, padding=pad, groups=c)
        mu_y = F.conv2d(yt, window, padding=pad, groups=c)
        s_xx = F.conv2d(xt * xt, window, padding=pad, groups=c) - mu_x * mu_x
        s_yy = F.conv2d(yt * yt, window, padding=pad, groups=c) - mu_y * mu_y
        s_xy = F.conv2d(xt * yt, window, padding=pad, groups=c) - mu_x * mu_y
        m = ((2 * mu_x * mu_y + c1) * (2 * s_xy + c2)) / ((mu_x ** 2 + mu_y ** 2 + c1) * (s_xx + s_yy + c2))
        value = m.mean()
        value.backward()
        return float(value), xt.grad

    return run


def cases(device: str = "cpu", quick: bool = False, tiny: bool = False, compare: bool = False) -> Iterator[dict]:
    dev = wp.get_device(device)
    sync = (lambda: wp.synchronize_device(dev)) if dev.is_cuda else None
    threads = default_threads()
    for side in SIZES["tiny" if tiny else ("quick" if quick else "full")]:
        x = np.random.default_rng(0).uniform(0.0, 1.0, (side, side, CHANNELS)).astype(np.float32)
        y = np.random.default_rng(1).uniform(0.0, 1.0, (side, side, CHANNELS)).astype(np.float32)
        xw, yw = wp.array(x, device=dev), wp.array(y, device=dev)

        def plain() -> None:
            with fast_paths.disabled():
                kssim.ssim(xw, yw)

        fns: dict[str, Callable[[], Any]] = {"fwd": lambda: kssim.ssim_map(xw, yw).mean(),
                                             "fwd_bwd": lambda: kssim.ssim(xw, yw)}
        if dev.is_cpu:
            fns["plain_fwd_bwd"] = plain
        missing: dict[str, str] = {}
        if compare:
            if dev.is_cuda or importlib.util.find_spec("torch") is None:
                missing = {"ref_missing": "torch reference runs on the CPU only" if dev.is_cuda else "torch (CPU)"}
            else:
                fns["ref"] = _torch_fwd_bwd(x, y, threads)
        t = time_medians(fns, repeats=REPEATS, sync=sync, settle_s=SETTLE_S if "ref" in fns else 0.0)
        row: dict[str, Any] = {"bench": "ssim.value_grad", "device": str(dev), "threads": threads,
                               "height": side, "width": side, "channels": CHANNELS, "dtype": "float32",
                               "fwd_s": t["fwd"], "fwd_bwd_s": t["fwd_bwd"], **missing}
        if "plain_fwd_bwd" in t:
            row["plain_fwd_bwd_s"] = t["plain_fwd_bwd"]
            row["speedup_fast_path"] = t["plain_fwd_bwd"] / t["fwd_bwd"]
        if "ref" in t:
            row.update(ref=REF, ref_fwd_bwd_s=t["ref"], speedup_fwd_bwd=t["ref"] / t["fwd_bwd"])
        yield row
