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
                          training loop calls it (shape and dtype checks only). `fwd_no_factor_s` (here
                          and in volume.composite_fwd) is the forward with keep_factor=False, as a render
                          that is never backpropagated calls it: the same outputs, no per-sample factors
                          kept (`fwd_s` keeps them for a backward, and is what PyTorch is compared with).
  * volume.field.<name>   points 1048576 in float32 for spheres (the 3 of the Video and 3D Vision
                          textbook chapter), grid (128^3 RGB), grid_sh2 (128^3, SH degree 2), hashgrid
                          (16 levels x 2^19 x 2, MLP 64-64) and pe_mlp (8 frequencies, MLP 64-64):
                          forward, and forward + backward to every parameter with random cotangents.
  * volume.composite_fwd  rays 16384 x 128 samples, forward only (`fwd_s`, checks on): the size at which
                          per-call overhead (checks, launch set-up) shows.
  * volume.spheres_render the textbook task: 64x64 rays x 64 samples through SphereField.textbook in
                          float32: the general path, dense_samples + render_samples + the image back in
                          NumPy (`render_s`), and the same image through the fused SphereField.render_dense
                          (`render_fused_s`), which is what experiments/volume_render_spheres times (on the
                          CPU the two give the image bit for bit, kernels.volume.spheres).
Each figure is the median of 3 runs (5 for compositing) after a warm-up (research.bench.time_median);
each run starts after 20 ms idle (`research.bench.SETTLE_S`), so that PyTorch's OpenMP workers, which
spin-wait after every op, are not timed as part of the drlab call that follows the reference.

`bound_s` (volume.composite) is the memory-bandwidth bound measured here: reading sigma, rgb and
delta once (20 bytes a sample in float32) with a NumPy sum split over the same threads;
`fwd_over_bound` = fwd_s / bound_s. `bound_max_s` reads the same bytes with an unsigned maximum
(less arithmetic per byte than NumPy's pairwise float32 sum, which on the bench host is not always
memory-bound: the same 168 MB took 42.5 ms by sum and 23.4 ms by maximum on one thread); `fwd_over_bound_max` = fwd_s /
bound_max_s; `fwd_no_factor_over_bound_max` = fwd_no_factor_s / bound_max_s. experiments/performance.py
judges the target on the tighter `bound_max_s` and shows both, for each forward.

With `compare=True` (drlab bench --compare), timed interleaved in the same `time_medians` call on
the same inputs, with the same thread count (torch.set_num_threads):
  * composite, composite_fwd: PyTorch, the cumprod form of the quadrature (what a NeRF codebase
    writes): alpha = 1 - exp(-sigma delta), T = cumprod(1 - alpha + 1e-10) shifted, w = alpha T,
    C = sum w c + (1 - sum w) b, D = sum w z, A = sum w; forward under no_grad (`ref_fwd_s`) and
    forward + autograd backward of <g_C, C> + <g_D, D> + <g_A, A> to sigma and rgb (`ref_fwd_bwd_s`);
  * spheres_render: the textbook's vectorised NumPy port (research.nerf.textbook), `ref_render_s`.
`speedup_<phase>` = ref_<phase>_s / <phase>_s (> 1: drlab is faster). Without PyTorch the composite
cases carry `ref_missing` instead.
"""

from __future__ import annotations

import os
from typing import Callable, Iterator

import numpy as np
import warp as wp

from research.bench import SETTLE_S, time_median, time_medians

COMPOSITE_RAYS, COMPOSITE_SAMPLES = 65536, 128
COMPOSITE_FWD_RAYS = 16384
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


def _torch_composite(arrays: dict, rays: int, samples: int, threads: int):
    """PyTorch reference closures (module docstring) on the same data, or None without PyTorch."""
    try:
        import torch
    except ImportError:
        return None
    torch.set_num_threads(threads)
    t = {k: torch.from_numpy(v.numpy()) for k, v in arrays.items()}  # zero-copy views of the host arrays
    bg = torch.zeros(3, dtype=t["sigma"].dtype)

    def forward(s, c):
        d = t["delta"].view(rays, samples)
        alpha = 1.0 - torch.exp(-s * d)
        ones = torch.ones(rays, 1, dtype=s.dtype)
        trans = torch.cumprod(torch.cat([ones, 1.0 - alpha + 1e-10], 1), 1)[:, :-1]
        w = alpha * trans
        acc = w.sum(1)
        rgb = (w[..., None] * c).sum(1) + (1.0 - acc)[:, None] * bg
        return rgb, (w * t["z"].view(rays, samples)).sum(1), acc

    def fwd():
        with torch.no_grad():
            return forward(t["sigma"].view(rays, samples), t["rgb"].view(rays, samples, 3))

    def fwd_bwd():
        s = t["sigma"].view(rays, samples).detach().requires_grad_(True)
        c = t["rgb"].view(rays, samples, 3).detach().requires_grad_(True)
        rgb, depth, acc = forward(s, c)
        loss = (rgb * t["g_rgb"]).sum() + (depth * t["g_d"]).sum() + (acc * t["g_d"]).sum()
        loss.backward()
        return s.grad, c.grad

    return {"fwd": fwd, "fwd_bwd": fwd_bwd, "name": f"torch {torch.__version__} (cumprod form, autograd)"}


def _read_bound(arrays: list[wp.array], bits: bool = False) -> Callable[[], None]:
    """A NumPy pass that reads every byte of `arrays` once, split over the launch threads: a float
    sum (bound_s), or with `bits` an unsigned maximum of the same bytes (bound_max_s), which does
    less arithmetic per byte than the pairwise float sum."""
    from kernels.launch import parallel_ranges

    flats = [a.numpy().reshape(-1) for a in arrays]
    if bits:
        flats = [f.view({4: np.uint32, 8: np.uint64}[f.itemsize]) for f in flats]
    reduce = np.max if bits else np.sum

    def read() -> None:
        for f in flats:
            parallel_ranges(lambda lo, hi, f=f: reduce(f[lo:hi]), f.shape[0])

    return read


def _composite_case(dev, threads: int, rays: int, samples: int, rng, sync, compare: bool, full: bool) -> dict:
    from kernels._arrays import value_checks
    from kernels.volume import Workspace, composite_backward, composite_forward, dense_offsets
    from kernels.volume.composite import composite_buffers, composite_grad_buffers

    n = rays * samples
    arr = lambda a, dt=wp.float32: wp.array(a, dtype=dt, device=dev)  # noqa: E731
    arrays = {"sigma": arr(rng.uniform(0.0, 0.5, n).astype(np.float32)),
              "rgb": arr(rng.uniform(0.0, 1.0, (n, 3)).astype(np.float32)),
              "delta": arr(np.full(n, 0.01, np.float32)),
              "z": arr(np.tile(np.linspace(1.0, 2.28, samples, dtype=np.float32), rays)),
              "g_rgb": arr(rng.normal(size=(rays, 3)).astype(np.float32)),
              "g_d": arr(rng.normal(size=rays).astype(np.float32))}
    sigma, rgb, delta, z, g_rgb, g_d = (arrays[k] for k in ("sigma", "rgb", "delta", "z", "g_rgb", "g_d"))
    offsets = arr(dense_offsets(rays, samples), wp.int32)

    # Output buffers allocated once, as in training (kernels.volume.workspace).
    ws = Workspace(dev)
    res_buf = composite_buffers(ws, rays, n, wp.float32)
    grad_buf = composite_grad_buffers(ws, n, wp.float32)
    res_buf_no_factor = composite_buffers(ws, rays, n, wp.float32, keep_factor=False)  # the same views, no factor

    def fwd(out=res_buf):
        return composite_forward(sigma, rgb, delta, z, offsets, device=dev, out=out)

    def fwd_no_factor():  # the forward of a render that is not backpropagated: no per-sample factors kept
        return composite_forward(sigma, rgb, delta, z, offsets, device=dev, out=res_buf_no_factor, keep_factor=False)

    def fwd_bwd(reuse=True):
        res = fwd(res_buf if reuse else None)
        composite_backward(sigma, rgb, delta, z, offsets, res, g_rgb, g_d, g_d, device=dev,
                           out=grad_buf if reuse else None)

    def fwd_unchecked():
        with value_checks(False):
            return fwd()

    row = {"bench": "volume.composite" if full else "volume.composite_fwd", "device": str(dev), "threads": threads,
           "rays": rays, "samples": samples}
    fns = {"fwd": fwd, "fwd_no_factor": fwd_no_factor}
    if full:
        fns.update(fwd_unchecked=fwd_unchecked, fwd_bwd=fwd_bwd)
        if dev.is_cpu:
            fns["bound"] = _read_bound([sigma, rgb, delta])
            fns["bound_max"] = _read_bound([sigma, rgb, delta], bits=True)
    ref = _torch_composite(arrays, rays, samples, threads) if compare and dev.is_cpu else None
    phases = ("fwd", "fwd_bwd") if full else ("fwd",)
    if ref is not None:
        fns.update({f"ref_{p}": ref[p] for p in phases})
    # Interleaved (research.bench.time_medians), so all see the same drift in machine speed, each
    # run after SETTLE_S idle: PyTorch's OpenMP workers spin for ~2 ms of a core after each op, which
    # fell on the drlab call timed next (the 16384-ray forward, ~4 ms on 2 threads, lost the most). The
    # fresh-buffer variant runs on its own: the memory it releases slows whatever runs next.
    times = time_medians(fns, repeats=5, sync=sync, settle_s=SETTLE_S)
    row["fwd_s"] = times["fwd"]
    row["fwd_no_factor_s"] = times["fwd_no_factor"]
    if full:
        row.update(fwd_bwd_s=times["fwd_bwd"], samples_per_s=n / times["fwd_bwd"],
                   fwd_bwd_fresh_buffers_s=time_median(lambda: fwd_bwd(reuse=False), repeats=5, sync=sync),
                   fwd_no_value_checks_s=times["fwd_unchecked"])
        if "bound" in times:
            row.update(bound_s=times["bound"], bound_gb_per_s=20 * n / times["bound"] / 1e9,
                       fwd_over_bound=times["fwd"] / times["bound"],
                       bound_max_s=times["bound_max"], fwd_over_bound_max=times["fwd"] / times["bound_max"],
                       fwd_no_factor_over_bound_max=times["fwd_no_factor"] / times["bound_max"])
    if compare:
        if ref is None:
            row["ref_missing"] = "torch (pip install drlab[bench])" if dev.is_cpu else "torch CPU reference on a CUDA run"
        else:
            row["ref"] = ref["name"]
            for p in phases:
                row[f"ref_{p}_s"] = times[f"ref_{p}"]
                row[f"speedup_{p}"] = times[f"ref_{p}"] / times[p]
    return row


def _spheres_case(dev, threads: int, tiny: bool, sync, compare: bool) -> dict:
    from kernels.volume import SphereField, render_samples
    from kernels.volume.sampling import dense_samples
    from research.nerf import textbook as tb

    h, w = (16, 16) if tiny else (tb.IMG_H, tb.IMG_W)
    focal = tb.FOCAL * w / tb.IMG_W
    origins, dirs = tb.textbook_rays(h, w, focal)
    t, delta = tb.textbook_t_delta()
    n_rays = origins.shape[0]
    field = SphereField.textbook(wp.float32, device=dev)

    def render():  # the general path (packed samples, the field's forward, the compositing kernel)
        s = dense_samples(origins.astype(np.float32), dirs.astype(np.float32),
                          np.tile(t.astype(np.float32), (n_rays, 1)), np.tile(delta.astype(np.float32), (n_rays, 1)),
                          device=dev)
        return render_samples(field, s, background=(0.0, 0.0, 0.0), t_threshold=0.0).rgb.numpy()

    def render_fused():  # the same image through SphereField.render_dense, as experiments/volume_render_spheres
        # (t and delta: one row broadcast to every ray, as the experiment passes them)
        rgb, _, _ = field.render_dense(origins.astype(np.float32), dirs.astype(np.float32),
                                       np.broadcast_to(t.astype(np.float32), (n_rays, t.shape[0])),
                                       np.broadcast_to(delta.astype(np.float32), (n_rays, delta.shape[0])),
                                       t_threshold=0.0)
        return rgb

    fns = {"render": render, "render_fused": render_fused}
    if compare:
        fns["ref_render"] = lambda: tb.render_image_vectorized(h, w, focal)
    times = time_medians(fns, repeats=5, sync=sync, settle_s=SETTLE_S)
    row = {"bench": "volume.spheres_render", "device": str(dev), "threads": threads, "rays": n_rays,
           "samples": tb.N_SAMPLES, "render_s": times["render"], "render_fused_s": times["render_fused"]}
    if compare:  # one reference, timed once per round, against both drlab paths
        row["ref"] = "numpy (research.nerf.textbook.render_image_vectorized, float64)"
        for phase in ("render", "render_fused"):
            row[f"ref_{phase}_s"] = times["ref_render"]
            row[f"speedup_{phase}"] = times["ref_render"] / times[phase]
    return row


def cases(device: str = "cpu", quick: bool = False, tiny: bool = False, compare: bool = False) -> Iterator[dict]:
    wp.init()
    dev = wp.get_device(device)
    threads = 1 if dev.is_cuda else int(os.environ.get("DRLAB_THREADS", os.cpu_count() or 1))
    sync = lambda: wp.synchronize_device(dev)  # noqa: E731
    scale = 16 if quick else 1
    rng = np.random.default_rng(0)

    rays, samples = (TINY_RAYS, TINY_SAMPLES) if tiny else (COMPOSITE_RAYS // scale, COMPOSITE_SAMPLES)
    yield _composite_case(dev, threads, rays, samples, rng, sync, compare, full=True)
    fwd_rays = TINY_RAYS if tiny else COMPOSITE_FWD_RAYS // scale
    yield _composite_case(dev, threads, fwd_rays, samples, rng, sync, compare, full=False)
    yield _spheres_case(dev, threads, tiny, sync, compare)

    arr = lambda a, dt=wp.float32: wp.array(a, dtype=dt, device=dev)  # noqa: E731
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
