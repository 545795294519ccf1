"""Benchmark family "volume": compositing and radiance-field kernels (kernels.volume).

Cases (full sizes below; `quick` divides them by 16; `tiny` runs every case at sizes that take
about a second in all -- 512 rays x 32 samples, 4096 points, 16^3 grids, a 2^12-entry hash table --
with the same keys, for the test suite):
  * volume.composite      rays 65536 x samples 128 in float32 (dense packing), forward (`fwd_s`) and
                          forward + backward (`fwd_bwd_s`), plus `samples_per_s` of forward + backward.
                          Densities are drawn so that no ray terminates early: every sample is work.
                          Inputs are validated on every call, as any caller's are. Outputs go to buffers
                          allocated once, as in training (kernels.volume.workspace);
                          `fwd_bwd_fresh_buffers_s` is the same with new arrays on every call, whose
                          first-touch page faults cost more than the backward kernel on the CPU.
                          `fwd_no_value_checks_s` is the forward inside value_checks(False), as a
                          training loop calls it (shape and dtype checks only).
  * volume.field.<name>   points 1048576 in float32 for spheres (the 3 of the Video and 3D Vision
                          textbook chapter), grid (128^3 RGB), grid_sh2 (128^3, SH degree 2), hashgrid
                          (16 levels x 2^19 x 2, MLP 64-64) and pe_mlp (8 frequencies, MLP 64-64):
                          forward, and forward + backward to every parameter with random cotangents.
Each figure is the median of 3 runs (5 for compositing) after a warm-up (research.bench.time_median).
"""

from __future__ import annotations

import os
from typing import Iterator

import numpy as np
import warp as wp

from research.bench import time_median, time_medians

COMPOSITE_RAYS, COMPOSITE_SAMPLES = 65536, 128
FIELD_POINTS = 1 << 20
TINY_RAYS, TINY_SAMPLES, TINY_POINTS, TINY_GRID, TINY_LOG2_TABLE = 512, 32, 4096, 16, 12
BOX = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def _fields(device: str, tiny: bool = False) -> dict:
    from kernels.volume import GridField, HashGridField, PEMLPField, SphereField

    res = (TINY_GRID,) * 3 if tiny else (128, 128, 128)
    log2_table = TINY_LOG2_TABLE if tiny else 19
    return {
        "spheres": lambda: SphereField.textbook(wp.float32, device),
        "grid": lambda: GridField(BOX, res, density_bias=-2.0, init_color_std=0.1, device=device),
        "grid_sh2": lambda: GridField(BOX, res, sh_degree=2, density_bias=-2.0, init_color_std=0.1, device=device),
        "hashgrid": lambda: HashGridField(BOX, n_levels=16, n_features=2, log2_table_size=log2_table, device=device),
        "pe_mlp": lambda: PEMLPField(BOX, n_freqs=8, device=device),
    }


def cases(device: str = "cpu", quick: bool = False, tiny: bool = False) -> Iterator[dict]:
    from kernels._arrays import value_checks
    from kernels.volume import Workspace, composite_backward, composite_forward, dense_offsets
    from kernels.volume.composite import composite_buffers, composite_grad_buffers

    wp.init()
    dev = wp.get_device(device)
    threads = 1 if dev.is_cuda else int(os.environ.get("DRLAB_THREADS", os.cpu_count() or 1))
    sync = lambda: wp.synchronize_device(dev)  # noqa: E731
    scale = 16 if quick else 1
    rng = np.random.default_rng(0)

    rays, samples = (TINY_RAYS, TINY_SAMPLES) if tiny else (COMPOSITE_RAYS // scale, COMPOSITE_SAMPLES)
    n = rays * samples
    arr = lambda a, dt=wp.float32: wp.array(a, dtype=dt, device=dev)  # noqa: E731
    sigma = arr(rng.uniform(0.0, 0.5, n).astype(np.float32))
    rgb = arr(rng.uniform(0.0, 1.0, (n, 3)).astype(np.float32))
    delta = arr(np.full(n, 0.01, np.float32))
    z = arr(np.tile(np.linspace(1.0, 2.28, samples, dtype=np.float32), rays))
    offsets = arr(dense_offsets(rays, samples), wp.int32)
    g_rgb = arr(rng.normal(size=(rays, 3)).astype(np.float32))
    g_d = arr(rng.normal(size=rays).astype(np.float32))

    # Output buffers allocated once, as in training (kernels.volume.workspace).
    ws = Workspace(dev)
    res_buf = composite_buffers(ws, rays, n, wp.float32)
    grad_buf = composite_grad_buffers(ws, n, wp.float32)

    def fwd(out=res_buf):
        return composite_forward(sigma, rgb, delta, z, offsets, device=dev, out=out)

    def fwd_bwd(reuse=True):
        res = fwd(res_buf if reuse else None)
        composite_backward(sigma, rgb, delta, z, offsets, res, g_rgb, g_d, g_d, device=dev,
                           out=grad_buf if reuse else None)

    def fwd_unchecked():
        with value_checks(False):
            return fwd()

    # Interleaved (research.bench.time_medians), so all see the same drift in machine speed. The
    # fresh-buffer variant runs on its own: the memory it releases slows whatever runs next.
    times = time_medians({"fwd": fwd, "fwd_unchecked": fwd_unchecked, "fwd_bwd": fwd_bwd}, repeats=5, sync=sync)
    t_f, t_fb = times["fwd"], times["fwd_bwd"]
    t_fb_alloc = time_median(lambda: fwd_bwd(reuse=False), repeats=5, sync=sync)
    yield {"bench": "volume.composite", "device": str(dev), "threads": threads, "rays": rays, "samples": samples,
           "fwd_s": t_f, "fwd_bwd_s": t_fb, "samples_per_s": n / t_fb,
           "fwd_bwd_fresh_buffers_s": t_fb_alloc, "fwd_no_value_checks_s": times["fwd_unchecked"]}

    points_n = TINY_POINTS if tiny else FIELD_POINTS // scale
    pts = arr(rng.uniform(-1.0, 1.0, (points_n, 3)).astype(np.float32))
    d = rng.normal(size=(points_n, 3))
    dirs = arr((d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32))
    gs = arr(rng.normal(size=points_n).astype(np.float32))
    gr = arr(rng.normal(size=(points_n, 3)).astype(np.float32))
    for name, make in _fields(device, tiny).items():
        field = make()
        dd = dirs if field.needs_dirs else None
        if name == "spheres":  # the chapter's spheres sit around z = 4
            p = arr(rng.uniform([-2.0, -1.5, 2.5], [2.5, 1.5, 6.0], (points_n, 3)).astype(np.float32))
        else:
            p = pts

        def f_fwd(field=field, p=p, dd=dd):
            return field.forward(p, dd)

        def f_fwd_bwd(field=field, p=p, dd=dd):
            out = field.forward(p, dd)
            field.backward(p, dd, out, gs, gr)

        yield {"bench": f"volume.field.{name}", "device": str(dev), "threads": threads, "points": points_n,
               "params": field.n_params(), "fwd_s": time_median(f_fwd, sync=sync),
               "fwd_bwd_s": time_median(f_fwd_bwd, sync=sync)}
        del field
