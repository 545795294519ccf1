"""Benchmark family "splat": Gaussian-splatting render, forward and forward + backward.

Case `splat.render` at (gaussians, height, width) = (2000, 128, 128) and
(100000, 512, 512), float32, on the named device (CPU: kernels.launch threads);
`tiny` runs (200, 32, 32) only, about a second in all (for `make test`).

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
  fwd_s      render(): projection, tile binning, both radix sorts, rasterisation;
  fwd_bwd_s  render() then render_backward() for a random image cotangent;
  fwd_bwd_camera_s  the same with want_camera=True (the pose and intrinsics gradients too).
Extra keys: visible splats, (tile, splat) entries, mean alpha.
"""

from __future__ import annotations

import math
from typing import Iterator

import numpy as np
import warp as wp

from kernels import splat as ks
from kernels.launch import default_threads
from research.bench import time_medians

CASES = ((2000, 128, 128), (100_000, 512, 512))
QUICK_CASES = ((2000, 128, 128),)
TINY_CASES = ((200, 32, 32),)
REPEATS = 3


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


def cases(device: str = "cpu", quick: bool = False, tiny: bool = False) -> Iterator[dict]:
    dev = wp.get_device(device)
    threads = 1 if dev.is_cuda else default_threads()
    for n, h, w in TINY_CASES if tiny else QUICK_CASES if quick else CASES:
        g, camera = bench_scene(n, h, w, device=dev)
        cot = wp.array(np.random.default_rng(1).normal(size=(h, w, 3)).astype(np.float32), device=dev)
        sync = lambda: wp.synchronize_device(dev)  # noqa: E731

        def fwd():
            return ks.render(g, camera)

        def fwd_bwd():
            ks.render_backward(g, ks.render(g, camera), cot)

        def fwd_bwd_camera():
            ks.render_backward(g, ks.render(g, camera), cot, want_camera=True)

        t = time_medians({"fwd": fwd, "fwd_bwd": fwd_bwd, "fwd_bwd_camera": fwd_bwd_camera}, repeats=REPEATS,
                         sync=sync)
        r = fwd()
        yield {"bench": "splat.render", "device": str(dev), "threads": threads, "gaussians": n, "height": h,
               "width": w, "fwd_s": t["fwd"], "fwd_bwd_s": t["fwd_bwd"],
               "fwd_bwd_camera_s": t["fwd_bwd_camera"],
               "visible": int((r.projection.radii.numpy() > 0).sum()), "tile_entries": r.tiles.n_entries,
               "mean_alpha": float(r.alpha.numpy().mean())}
