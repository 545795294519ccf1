"""Benchmark family "splat": Gaussian-splatting render, forward and forward + backward.

Case `splat.render` at (gaussians, height, width) = (2000, 128, 128), (100000, 512, 512) and,
forward only, (1000000, 1080, 1920) (full sizes only), float32, on the named device (CPU:
kernels.launch threads); `quick` runs the first, `tiny` (200, 32, 32) only, about a second in all
(for `make test`).

The scene (`bench_scene`): means uniform in a ball of radius 1 seen from 3.5 units
with a 50 degree field of view; per-axis scales log-uniform within a factor e of
0.06 (2000 / n)^(1/3) (so the splats of the bigger case are smaller and the ball
is covered about as densely); random rotations; opacities sigmoid(N(0, 1.5)); SH
degree 3 with N(0, 0.3) coefficients. Every splat is in view, and the ball is a
semi-transparent cloud (mean alpha ~0.35, few pixels saturate), so most pixels
walk their tile's whole list: harder than a converged scene of opaque surfaces,
where the T < 1e-4 stop ends most pixels early.

Phases (medians of REPEATS runs after a warm-up, kernels.splat; the parameters are
wp.arrays on the device, so every result stays there):
  fwd_s      render(): projection, tile binning with its sorts, rasterisation;
  fwd_bwd_s  render() then render_backward() for a random image cotangent;
  fwd_bwd_camera_s  the same with want_camera=True (the pose and intrinsics gradients too);
  project_s, bin_s, raster_s  the forward's stages alone (projection; tile binning with its
             sorts; rasterisation of the binned tiles), for where the forward's time goes;
  rasterize_s  binning plus rasterisation of the projected splats: what the dense reference does.
The forward-only case times fwd_s and the stages. Extra keys: visible splats, (tile, splat)
entries, mean alpha.

Reference (`compare=True`, cases with gaussians x pixels <= DENSE_MAX only, since it evaluates
every Gaussian at every pixel): a dense PyTorch rasteriser of the same projected splats
(`_torch_dense_raster`): the splats sorted by depth, alpha = min(a_max, o exp(-1/2 d^T Q d)) of
every splat at every pixel (zero where below 1/255 or the exponent is positive), the
transmittance as a cumulative product, the stop at T < 1e-4 as a prefix mask, colours by a
matrix product; pixels in blocks of DENSE_BLOCK, with drlab's thread count. It is timed
interleaved with `rasterize_s` (ref_rasterize_s, speedup_rasterize), and `ref_max_abs_diff` is
its largest difference from drlab's image (float rounding only: both skip the same splats).
Larger cases carry `ref_skipped` instead.
"""

from __future__ import annotations

import math
from typing import Iterator

import numpy as np
import warp as wp

from kernels import splat as ks
from kernels.launch import default_threads
from research.bench import SETTLE_S, time_medians

CASES = ((2000, 128, 128, True), (100_000, 512, 512, True), (1_000_000, 1080, 1920, False))
QUICK_CASES = ((2000, 128, 128, True),)
TINY_CASES = ((200, 32, 32, True),)
REPEATS = 3
DENSE_MAX = 64_000_000  # gaussians x pixels of the largest case the dense reference runs
DENSE_BLOCK = 2048  # pixels per block of the dense reference


def bench_scene(n: int, height: int, width: int, seed: int = 0, dtype=np.float32, device=None):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    means = d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(0, 1, (n, 1)) ** (1 / 3)
    # Splat size falls with the cube root of the count, as a fixed scene is covered by more, smaller splats.
    size = 0.06 * (2000 / n) ** (1 / 3)
    log_scales = np.log(size) + rng.uniform(-1.0, 1.0, (n, 3))
    params = {"means": means, "log_scales": log_scales, "quats": rng.normal(size=(n, 4)),
              "opacity_logits": rng.normal(0.0, 1.5, n), "sh": rng.normal(0.0, 0.3, (n, 16, 3))}
    f = (width / 2) / math.tan(math.radians(50) / 2)
    view = np.eye(4)
    view[2, 3] = 3.5
    camera = ks.SplatCamera(view, np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]]), width, height)
    dev = wp.get_device(device)
    g = ks.gaussian_inputs(*(wp.array(params[k].astype(dtype), device=dev)
                             for k in ("means", "log_scales", "quats", "opacity_logits", "sh")), device=dev)
    return g, camera


def _torch_dense_raster(proj, width: int, height: int, threads: int, mode: str = "3dgs"):
    """A dense PyTorch rasteriser of drlab's projected splats (module docstring), or None without PyTorch."""
    try:
        import torch
    except ImportError:
        return None
    torch.set_num_threads(threads)
    radii = proj.radii.numpy()
    keep = np.flatnonzero(radii > 0)
    keep = keep[np.argsort(proj.depths.numpy()[keep], kind="stable")]
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a.numpy()[keep]))  # noqa: E731
    means, conics, colors, opac = t(proj.means2d), t(proj.conics), t(proj.colors), t(proj.opacities)
    dtype = means.dtype
    ys, xs = torch.meshgrid(torch.arange(height, dtype=dtype) + 0.5, torch.arange(width, dtype=dtype) + 0.5,
                            indexing="ij")
    pix = torch.stack([xs.reshape(-1), ys.reshape(-1)], 1)
    alpha_max = ks.ALPHA_MAX_OF[mode]

    def raster():
        out = torch.empty(height * width, 3, dtype=dtype)
        with torch.no_grad():
            for lo in range(0, pix.shape[0], DENSE_BLOCK):
                d = means[None] - pix[lo:lo + DENSE_BLOCK, None]  # (P, N, 2)
                dx, dy = d[..., 0], d[..., 1]
                power = -0.5 * (conics[:, 0] * dx * dx + conics[:, 2] * dy * dy) - conics[:, 1] * dx * dy
                alpha = torch.clamp(opac * torch.exp(power), max=alpha_max)
                alpha = torch.where((power > 0) | (alpha < ks.ALPHA_MIN), torch.zeros((), dtype=dtype), alpha)
                trans = torch.cumprod(1.0 - alpha, 1)  # T after each splat; non-increasing
                blended = trans >= ks.T_MIN if mode == "3dgs" else trans > ks.T_MIN
                trans_before = torch.cat([torch.ones(trans.shape[0], 1, dtype=dtype), trans[:, :-1]], 1)
                out[lo:lo + DENSE_BLOCK] = (alpha * trans_before * blended) @ colors
        return out.view(height, width, 3)

    return raster


def cases(device: str = "cpu", quick: bool = False, tiny: bool = False, compare: bool = False) -> Iterator[dict]:
    from kernels.splat.projection import project_wp, sh_degree_of
    from kernels.splat.raster import background_array, rasterize_wp
    from kernels.splat.render import _splats_2d
    from kernels.splat.tiles import bin_tiles

    dev = wp.get_device(device)
    threads = 1 if dev.is_cuda else default_threads()
    for n, h, w, backward in TINY_CASES if tiny else QUICK_CASES if quick else CASES:
        g, camera = bench_scene(n, h, w, device=dev)
        sync = lambda: wp.synchronize_device(dev)  # noqa: E731
        deg = sh_degree_of(tuple(g.sh.shape), None)
        bg = background_array(g.inputs(), None)
        proj = project_wp(g, camera, deg, False, ks.DEFAULT_MODE)
        s2 = _splats_2d(g, proj)
        tiles = bin_tiles(s2, w, h)
        fns = {"fwd": lambda: ks.render(g, camera),
               "project": lambda: project_wp(g, camera, deg, False, ks.DEFAULT_MODE),
               "bin": lambda: bin_tiles(s2, w, h),
               "raster": lambda: rasterize_wp(s2, w, h, bg, tiles),
               "rasterize": lambda: rasterize_wp(s2, w, h, bg)}
        if backward:
            cot = wp.array(np.random.default_rng(1).normal(size=(h, w, 3)).astype(np.float32), device=dev)
            fns["fwd_bwd"] = lambda: ks.render_backward(g, ks.render(g, camera), cot)
            fns["fwd_bwd_camera"] = lambda: ks.render_backward(g, ks.render(g, camera), cot, want_camera=True)
        ref = None
        row: dict = {}
        if compare:
            if n * h * w > DENSE_MAX:
                row["ref_skipped"] = f"dense reference only up to gaussians x pixels = {DENSE_MAX}"
            elif not dev.is_cpu:
                row["ref_missing"] = "torch CPU reference on a CUDA run"
            else:
                ref = _torch_dense_raster(proj, w, h, threads)
                if ref is None:
                    row["ref_missing"] = "torch (pip install drlab[bench])"
                else:
                    fns["ref_rasterize"] = ref
        t = time_medians(fns, repeats=REPEATS, sync=sync, settle_s=SETTLE_S)
        r = ks.render(g, camera)
        out = {"bench": "splat.render", "device": str(dev), "threads": threads, "gaussians": n, "height": h,
               "width": w, **{f"{k}_s": v for k, v in t.items() if not k.startswith("ref_")},
               "visible": int((r.projection.radii.numpy() > 0).sum()), "tile_entries": r.tiles.n_entries,
               "mean_alpha": float(r.alpha.numpy().mean())}
        if ref is not None:
            import torch

            out.update(ref=f"torch {torch.__version__} dense rasteriser (every splat at every pixel)",
                       ref_rasterize_s=t["ref_rasterize"], speedup_rasterize=t["ref_rasterize"] / t["rasterize"],
                       ref_max_abs_diff=float(np.abs(ref().numpy() - r.rgb.numpy()).max()))
        yield {**out, **row}
