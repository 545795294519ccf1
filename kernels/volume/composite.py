"""Volume-rendering compositing along rays, forward and hand-written backward.

Quadrature of the volume-rendering integral (Max 1995; NeRF, Mildenhall et al. 2020, eq. 3).
Ray r owns the packed samples k = o_r .. o_{r+1}-1 (``ray_offsets``), in front-to-back order,
each with density sigma_k >= 0, colour c_k (3), interval length delta_k >= 0 and depth z_k:

    alpha_k = 1 - exp(-sigma_k delta_k)
    T_k     = prod_{j<k} (1 - alpha_j) = exp(-sum_{j<k} sigma_j delta_j)      (T_0 = 1)
    w_k     = T_k alpha_k
    C       = sum_k w_k c_k + T_N b          colour over the background b
    D       = sum_k w_k z_k                  expected depth (z-depth when z_k is)
    A       = 1 - T_N = sum_k w_k            accumulated opacity

Early ray termination (instant-ngp, Mueller et al. 2022): the loop stops before sample k as
soon as T_k < t_threshold; the samples processed are counted (``n_used``) and T_N is the
transmittance after the last one. ``t_threshold = 0`` disables termination.

Backward (hand-written; Warp's tape is wrong through a loop with carried state, docs/warp.md).
For output cotangents (g_C, g_D, g_A) and f_k = g_C . c_k + g_D z_k, the scalar
L = g_C . C + g_D D + g_A A has

    dL/dc_k     = g_C w_k
    dL/dsigma_k = delta_k [ T_{k+1} f_k - S_k + T_N (g_A - g_C . b) ],   S_k = sum_{j>k} w_j f_j

(dw_j/dsigma_k is delta_k T_{k+1} for j = k and -delta_k w_j for j > k; dT_N/dsigma_k =
-delta_k T_N.) The backward kernel is a second pass over each ray that starts from the
forward's final values, as instant-ngp does: the total sum_j w_j f_j = g_C . (C - T_N b) + g_D D
comes from the forward outputs, and S_k = total - sum_{j<=k} w_j f_j is obtained by
subtracting the running prefix while T_k is rebuilt front to back from the factors
exp(-sigma_k delta_k) that the forward stored (``CompositeResult.factor``): the same products
as the forward, so T_k and w_k agree bit for bit, and no exponential is evaluated twice (that
was more than half the backward kernel's time on the CPU: 36 -> 16 ms at 65536 x 128
samples). Samples after the termination point get zero gradient; a ray with no samples returns
the background with zero gradient.

One thread per ray: every thread writes only its own ray's outputs and its own samples'
gradients, so both kernels run as split launches on the CPU (kernels.launch's guided chunks, at
least _CHUNK_SAMPLES samples on average), each launch thread packing the arguments once into a
recorded launch whose size and offset it then sets chunk by chunk (_launch). The loops take the
samples four at a time where four consecutive ones start at a multiple of 4 (vec4 loads of the
factors and depths, vec3 loads of the colours) and none of the four terminates the ray, one at a
time elsewhere: the same operations in the same order, so the outputs are bit for bit those of a
one-at-a-time loop, with a quarter of the loop and index arithmetic (Warp's CPU code computes
and wraps every index).

Factors on the CPU. Warp's scalar exp costs 3.7 ns a sample on one core, more than the rest of
the forward loop (3.0 ns): on the CPU the factors exp(-sigma_k delta_k) of all N samples are
filled in first by NumPy's vectorised exp (about 1 ns a sample), split over the launch threads,
and the kernel reads them. NumPy's float32 exp is within 2 ulp of the exact value (Warp's within
0.5 ulp), so float32 outputs can differ from the in-kernel exponential by a few ulp of each
factor (relative 2.4e-7); float64 is within 1 ulp either way. Samples after early termination
get factors too (unused). On CUDA the kernel evaluates the exponential itself. In the float32 SIMD
forward (below) the kernel evaluates them too, with NumPy's float32 exp reproduced in its lanes
(kernels._npexp, the same bits for every float32 input), saving the pass; `FUSED_EXP = False`, a
NumPy whose exp is another loop (checked once on a fixed set), or offsets that do not cover the N
samples keep the pass.

Renders that are never backpropagated (test views, depth and opacity maps for metrics) pass
`keep_factor=False`: the result's `factor` is None and every other output is bit for bit the same.
The fused float32 SIMD forward then keeps each group's factors in a two-slot per-thread ring
(composite_cpu.RING samples a slot) instead of the N-sized array (8 bytes a sample less: the write
and its read for ownership), where every group of eight rays fits a slot; any other path fills a
scratch array that is not returned. composite_backward, render_backward and render_backward_rays
refuse such a result (ValueError, before any kernel runs).

SIMD kernels on the CPU. In float32 the CPU forward and backward run kernels.volume.composite_cpu
instead of the Warp kernels: eight rays a thread in vector lanes, each lane the same float32
operations in the same order as one thread here, so the same outputs bit for bit (tests compare
the two); `SIMD_FORWARD = False` / `SIMD_BACKWARD = False` keep the Warp kernels. float64 and CUDA
always run the Warp kernels. With the CPU fast paths off (kernels.fast_paths) the CPU takes the CUDA
route throughout: no NumPy factor pass, no C++, the values checked before the launch.

Value checks on the CPU ride on passes the forward makes anyway instead of six separate single-
threaded passes over the samples. sigma and delta: while a block of them is in cache for the
factors, one unsigned maximum of its bits per array tells whether every value is finite and >= 0
(before the launch; in the fused SIMD forward, in the kernel's factor loop, read after it). rgb and
z: the kernel's sums C and D are NaN or infinite if any processed colour or depth is (the weights
are finite once sigma and delta are), so each ray flags itself from its own sums, adding up only its
samples after early termination; after the launch the flags are read. Only on a flag (or a doubt:
-0.0, sums that overflow) do the exact checks of kernels._arrays run, and they raise the ValueError
naming the argument. A bad rgb or z (and, in the fused forward, sigma or delta) is so reported after
the launch: the outputs (and `out` buffers) are then to be discarded.

Inputs follow the array contract (kernels._arrays): NumPy in gives NumPy out, wp.arrays in give
wp.arrays on their device; inside `value_checks(False)` only shapes and dtypes are checked.

This module is the host side (the entry points, their checks, the factor pass, the split launches);
the Warp kernels are in kernels.volume.composite_kernels, the float32 CPU kernels in
kernels.volume.composite_cpu.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels.launch import default_threads, guided_bounds, parallel_items, parallel_ranges
from kernels import _npexp, fast_paths
from kernels.volume import composite_cpu
from kernels.volume._checks import check_ray_offsets
from kernels.volume.composite_kernels import _BACKWARD, _FORWARD, _VEC3, _VEC4
from kernels.volume.workspace import Workspace

DEFAULT_T_THRESHOLD = 1e-4
# On the CPU in float32, the forward runs kernels.volume.composite_cpu (eight rays a thread in vector
# lanes, bit for bit the Warp kernel); False keeps the Warp kernel (tests compare the two).
SIMD_FORWARD = True
SIMD_BACKWARD = True  # the same for composite_backward
# In the SIMD forward, the kernel evaluates the factors exp(-sigma delta) itself with NumPy's float32 exp
# reproduced (kernels._npexp), instead of NumPy's pass before the launch, where that exp gives np.exp's bits on
# this CPU (checked once on a fixed set); False keeps NumPy's pass.
FUSED_EXP = True


@dataclass
class CompositeResult:
    """Per-ray outputs of `composite_forward`, in the kind of its inputs (NumPy or wp.arrays)."""

    rgb: A.ArrayLike  # (R, 3) colour over the background
    depth: A.ArrayLike  # (R,) expected depth sum_k w_k z_k
    opacity: A.ArrayLike  # (R,) 1 - T_N
    transmittance: A.ArrayLike  # (R,) T_N, transmittance after the last processed sample
    n_used: A.ArrayLike  # (R,) int32, samples processed before early termination
    # (N,) exp(-sigma_k delta_k) of every processed sample (entries past termination are not written).
    # The backward reads it rather than recomputing the exponential. None when composite_forward ran with
    # keep_factor=False (a render that is not backpropagated): such a result cannot be backpropagated.
    factor: A.ArrayLike | None


def _result_layout(n_rays: int, n_samples: int, dtype: Any) -> dict[str, tuple[tuple[int, ...], Any]]:
    """Shape and dtype of every CompositeResult field."""
    return {"rgb": ((n_rays, 3), dtype), "depth": ((n_rays,), dtype), "opacity": ((n_rays,), dtype),
            "transmittance": ((n_rays,), dtype), "n_used": ((n_rays,), wp.int32), "factor": ((n_samples,), dtype)}


def composite_buffers(workspace: Workspace, n_rays: int, n_samples: int, dtype: Any,
                      keep_factor: bool = True) -> CompositeResult:
    """`out` buffers for composite_forward: views into `workspace` (names "composite.<field>"); with
    keep_factor False, `factor` is None (for composite_forward(..., keep_factor=False))."""
    return CompositeResult(**{k: (None if k == "factor" and not keep_factor
                                  else workspace.array(f"composite.{k}", shape, t))
                              for k, (shape, t) in _result_layout(n_rays, n_samples, dtype).items()})


def check_keep_factor(keep_factor: Any) -> None:
    """ValueError unless `keep_factor` is a bool (composite_forward's, and the renders' that pass it on)."""
    if not isinstance(keep_factor, (bool, np.bool_)):
        raise ValueError(f"keep_factor: expected a bool, got {type(keep_factor).__name__}")


def check_backpropagatable(name: str, result: CompositeResult) -> None:
    """ValueError if `result` (named `name`) came from a forward with keep_factor=False: it holds no factors."""
    if result.factor is None:
        raise ValueError(f"{name}: this result was computed with keep_factor=False and holds no per-sample factors "
                         "(result.factor is None), so it cannot be backpropagated; run the forward with "
                         "keep_factor=True (the default) for a result to differentiate")


def composite_grad_buffers(workspace: Workspace, n_samples: int, dtype: Any) -> tuple[wp.array, wp.array]:
    """`out` buffers for composite_backward: (grad_sigma (N,), grad_rgb (N, 3)) views into `workspace`."""
    return (workspace.array("composite.grad_sigma", (n_samples,), dtype),
            workspace.array("composite.grad_rgb", (n_samples, 3), dtype))


def dense_offsets(n_rays: int, n_samples: int) -> np.ndarray:
    """ray_offsets for R rays with S samples each: [0, S, 2S, ..., RS] (int32)."""
    A.check_int("n_rays", n_rays, minimum=1)
    A.check_int("n_samples", n_samples, minimum=1)
    return (np.arange(n_rays + 1, dtype=np.int64) * n_samples).astype(np.int32)


# Samples per NumPy block in the CPU factor pass: sigma, delta and factor of a block (768 KB in
# float32) stay in a core's L2 cache between the multiply, the exp and the value checks.
_FILL_BLOCK = 1 << 16
# The largest finite float as an unsigned integer: a non-negative finite float's bits are at most
# this, and a negative number (sign bit), -0.0, inf or NaN have larger bits.
_MAX_FINITE_BITS = {np.dtype(np.float32): (np.uint32, np.uint32(0x7F7FFFFF)),
                    np.dtype(np.float64): (np.uint64, np.uint64(0x7FEFFFFFFFFFFFFF))}


# Split launches (kernels.launch): a chunk of rays holds at least _CHUNK_SAMPLES samples on average
# (~0.2 ms of kernel on a core, against ~40-80 us of Python a launch) and at least _CHUNK_RAYS rays.
_CHUNK_SAMPLES = 1 << 17
_CHUNK_RAYS = 256


def _min_chunk(n_rays: int, n: int) -> int:
    """Smallest chunk of rays for a split launch: _CHUNK_SAMPLES samples on average, at least _CHUNK_RAYS."""
    return max(_CHUNK_RAYS, _CHUNK_SAMPLES * n_rays // max(n, 1))


_LOADED: set[int] = set()  # id() of the kernels (one per dtype) launched here once: module compiled and loaded


def _launch(a: A.Inputs, kernel: Any, dim: int, inputs: list[Any], min_chunk: int) -> None:
    """Launch a kernel of this module (last parameter `offset`) over [0, dim) as a split launch.

    On the CPU with several threads, the chunks are kernels.launch's guided chunks, pulled in order by
    the launch threads as in launch_split, but each thread packs the arguments once into a recorded
    launch (wp.Launch) and a chunk only sets its size and offset: ~10 us of Python a chunk instead
    of the ~40-100 us of a wp.launch, which holds the GIL that the other threads' launches wait for.
    """
    threads = default_threads()
    if dim <= 0 or not a.device.is_cpu or threads == 1 or dim < 2 * min_chunk:
        a.launch(kernel, dim, inputs, min_chunk=min_chunk)
        return
    bounds = guided_bounds(dim, threads, min_chunk)
    n_args = len(kernel.adj.args)
    launches: dict[int, Any] = {}

    def run(j: int) -> None:
        lo, size = bounds[j]
        tid = threading.get_ident()
        rec = launches.get(tid)
        if rec is None:
            launches[tid] = wp.launch(kernel, dim=size, inputs=[*inputs, lo], device=a.device, record_cmd=True)
            rec = launches[tid]
        else:
            rec.set_dim(size)
            rec.set_param_at_index_from_ctype(n_args - 1, lo)
        rec.launch()

    first = 0
    if id(kernel) not in _LOADED:  # one chunk alone compiles and loads the module first
        run(0)
        _LOADED.add(id(kernel))
        first = 1
    parallel_items(lambda i: run(first + i), len(bounds) - first)


def _host_passes(device: wp.Device) -> bool:
    """Whether the CPU route runs: the factor pass by NumPy and the C++ kernels (kernels.fast_paths).
    Otherwise the CUDA route runs, also on the CPU: the values checked before the launch, the factors
    evaluated by the Warp kernel itself."""
    return device.is_cpu and fast_paths.enabled()


def _fill_factor(sigma: wp.array, delta: wp.array, factor: wp.array, check: bool) -> int:
    """On the CPU, factor = exp(-sigma delta) for every sample with NumPy's vectorised exp, in
    cache-sized blocks split over the launch threads; returns 1 (the kernel then reads the
    factors), or 0 on CUDA (the kernel evaluates them, and nothing is checked here).

    With `check`, the same pass also tests sigma and delta while each block is in cache: >= 0
    and finite as ONE unsigned maximum of their bits per block (_MAX_FINITE_BITS). Any doubt
    (including -0.0) runs the exact checks of kernels._arrays, which raise the ValueError naming
    the argument. See the module docstring for the rounding of the
    factors.
    """
    if not _host_passes(factor.device):
        return 0
    s, d, f = sigma.numpy(), delta.numpy(), factor.numpy()  # zero-copy views of host arrays
    uint, top = _MAX_FINITE_BITS[f.dtype]
    s_bits, d_bits = s.view(uint), d.view(uint)
    doubt: list[bool] = []

    def fill(lo: int, hi: int) -> None:
        bad = False
        for b in range(lo, hi, _FILL_BLOCK):
            e = min(b + _FILL_BLOCK, hi)
            out = f[b:e]
            np.multiply(s[b:e], d[b:e], out=out)
            np.negative(out, out=out)
            np.exp(out, out=out)
            if check:
                bad = bad or s_bits[b:e].max() > top or d_bits[b:e].max() > top
        if bad:
            doubt.append(True)

    parallel_ranges(fill, f.shape[0])
    if doubt:
        A.check_at_least("sigma", sigma, 0.0)
        A.check_at_least("delta", delta, 0.0)
    return 1


def _groups_fit(offsets: wp.array, n_rays: int) -> bool:
    """Every group of composite_cpu.LANES consecutive rays holds at most composite_cpu.RING samples (the forward's
    factor ring; checked offsets, covering N from 0)."""
    if n_rays == 0:
        return True
    h = offsets.numpy()  # host array: a zero-copy view
    lanes = composite_cpu.LANES
    ends = np.minimum(np.arange(lanes, n_rays + lanes, lanes), n_rays)
    return int((h[ends].astype(np.int64) - h[0:n_rays:lanes]).max()) <= composite_cpu.RING


_NO_FACTOR: dict[Any, wp.array] = {}  # device alias -> a 1-entry float32 array: the ring forward's unused `factor`


def _no_factor(device: wp.Device) -> wp.array:
    arr = _NO_FACTOR.get(device.alias)
    if arr is None:
        arr = _NO_FACTOR[device.alias] = wp.zeros(1, dtype=wp.float32, device=device)
    return arr


def _covers(offsets: wp.array, n: int) -> bool:
    """offsets[0] = 0, offsets[-1] = n and non-decreasing (as checked values always are), so that the rays'
    samples are all N: the fused forward fills the factors ray group by ray group, the pass before it all N."""
    h = offsets.numpy()  # host array: a zero-copy view
    if h.shape[0] < 2 or int(h[0]) != 0 or int(h[-1]) != n:
        return False
    return A.values_checked() or bool(np.all(h[1:] >= h[:-1]))


_BACKGROUNDS: dict[tuple, wp.array] = {}  # (bytes, dtype, device) -> a checked (1, 3) background


def _background(a: A.Inputs, background: Any, n_rays: int) -> tuple[wp.array, int]:
    """The background as a (1, 3) or (R, 3) array of the call's dtype, and whether it is per ray.

    A wp.array must have the call's dtype; anything else (a tuple, a NumPy array) is converted.
    """
    bg = background if isinstance(background, wp.array) else np.asarray(background, dtype=a.np_dtype)
    if tuple(bg.shape) == (3,):
        bg = bg.reshape((1, 3))
    if tuple(bg.shape) not in ((1, 3), (n_rays, 3)):
        raise ValueError(f"background: expected shape (3,) or (R, 3) = ({n_rays}, 3), got {tuple(bg.shape)}")
    if isinstance(bg, wp.array) or bg.shape[0] != 1:
        return a.floats("background", bg), int(bg.shape[0] != 1)
    # One colour given on the host (the usual tuple): its checked device copy is kept, so that a
    # call does not pay for a new wp.array (~30 us of Python) each time.
    key = (bg.tobytes(), bg.dtype.str, a.device.alias)
    arr = _BACKGROUNDS.get(key)
    if arr is None:
        arr = a.floats("background", bg)
        if np.isfinite(bg).all():  # only a valid colour is kept (value checks may be off now)
            if len(_BACKGROUNDS) >= 64:
                _BACKGROUNDS.clear()
            _BACKGROUNDS[key] = arr
    return arr, 0


def _samples(a: A.Inputs, sigma: Any, rgb: Any, delta: Any, z: Any, ray_offsets: Any, values: bool
             ) -> tuple[list[wp.array], int, int]:
    """[sigma, rgb, delta, z, ray_offsets] as wp.arrays, the sample count N and the ray count R.

    Shapes, dtypes and the offsets are checked here. `values` True checks the sample values here
    only on CUDA: on the CPU the forward checks sigma and delta in its factor pass
    (_fill_factor, before the launch) and rgb and z through its kernel's sums (module
    docstring). The backward passes False (the forward checked them).
    """
    on_cuda = values and not _host_passes(a.device)
    s = a.floats("sigma", sigma, (None,), finite=False)
    n = s.shape[0]
    c = a.floats("rgb", rgb, (n, 3), finite=on_cuda)
    d = a.floats("delta", delta, (n,), finite=False)
    zz = a.floats("z", z, (n,), finite=on_cuda)
    if on_cuda:
        A.check_at_least("sigma", s, 0.0)
        A.check_at_least("delta", d, 0.0)
    offsets = check_ray_offsets(a, "ray_offsets", ray_offsets, n)
    return [s, c, d, zz, offsets], n, offsets.shape[0] - 1


def composite_forward(
    sigma: A.ArrayLike,
    rgb: A.ArrayLike,
    delta: A.ArrayLike,
    z: A.ArrayLike,
    ray_offsets: A.ArrayLike,
    background: Any = (0.0, 0.0, 0.0),
    t_threshold: float = DEFAULT_T_THRESHOLD,
    device: str | wp.Device | None = None,
    out: CompositeResult | None = None,
    keep_factor: bool = True,
) -> CompositeResult:
    """Composite packed samples front to back (module docstring); one thread per ray.

    sigma (N,) >= 0, rgb (N, 3), delta (N,) >= 0, z (N,) in float32 or float64 (one dtype),
    ray_offsets (R+1,) integer, background (3,) or (R, 3). Returns a CompositeResult in the kind of
    `sigma` (NumPy arrays, or wp.arrays on the device). `out`, if given, is a CompositeResult of
    wp.arrays that receives the outputs and is returned: reusing buffers saves the page faults of
    fresh ones (kernels.volume.workspace).

    keep_factor=False is for renders that are never backpropagated (test views, depth or opacity maps for
    metrics): the result's `factor` is None, and every other output is bit for bit keep_factor=True's.
    composite_backward (and render_backward) refuse such a result. The float32 CPU forward then keeps a
    group's factors in a small per-thread ring and writes no per-sample array (no N-sized allocation, 8
    bytes a sample less to move); elsewhere the factors go to a scratch array that is not returned.
    `out.factor` is neither checked nor written then (it may be None).
    """
    check_keep_factor(keep_factor)
    a = A.Inputs(device, sigma, rgb, delta, z, ray_offsets)
    args, n, n_rays = _samples(a, sigma, rgb, delta, z, ray_offsets, values=True)
    t_threshold = A.check_float("t_threshold", t_threshold, nonnegative=True)
    if not t_threshold < 1.0:
        raise ValueError(f"t_threshold: expected a value in [0, 1), got {t_threshold}")
    bg, per_ray = _background(a, background, n_rays)
    layout = _result_layout(n_rays, n, a.scalar)
    del layout["factor"]  # below: only with keep_factor
    if out is None:
        res = CompositeResult(**{k: a.empty(shape, t) for k, (shape, t) in layout.items()}, factor=None)
    else:
        res = CompositeResult(**{k: A.check_out(f"out.{k}", getattr(out, k), shape, t, a.device)
                                 for k, (shape, t) in layout.items()}, factor=None)
    if keep_factor:
        factor = res.factor = (a.empty(n) if out is None else
                                 A.check_out("out.factor", out.factor, (n,), a.scalar, a.device))
    s, c, d, zz, offsets = args
    check = A.values_checked() and _host_passes(a.device)  # else _samples checked the values
    simd = (_host_passes(a.device) and a.scalar == wp.float32 and SIMD_FORWARD and 3 * n < 2**31
            and all(x.is_contiguous for x in (s, c, d, zz, offsets)) and (not keep_factor or factor.is_contiguous))
    fused = simd and FUSED_EXP and _covers(offsets, n) and _npexp.numpy_agrees()
    # keep_factor False: the fused SIMD forward keeps the factors in its per-thread ring (every group of eight
    # rays within composite_cpu.RING samples); any other path fills a scratch array that is not returned
    ring = fused and not keep_factor and _groups_fit(offsets, n_rays)
    if not keep_factor:
        factor = _no_factor(a.device) if ring else a.empty(n)
    factor_given = 1 if fused else _fill_factor(s, d, factor, check) if _host_passes(a.device) else 0
    bad = a.empty(n_rays if check else 1, wp.int32)
    if simd:
        # CPU, float32: eight rays a thread in vector lanes, the same outputs bit for bit (composite_cpu);
        # fused: the kernel fills the factors itself (NumPy's exp reproduced), flagging bad sigma or delta as 2
        rays_a_thread = composite_cpu.LANES * composite_cpu.GROUPS
        _launch(a, composite_cpu.forward_kernel(), (n_rays + rays_a_thread - 1) // rays_a_thread,
                [s, d, int(fused), int(not ring), factor, c, zz, offsets, bg, per_ray, a.s(t_threshold), res.rgb,
                 res.depth, res.opacity, res.transmittance, res.n_used, int(check), bad],
                min_chunk=max(1, _min_chunk(n_rays, n) // rays_a_thread))
        if fused and check and n_rays and bool((bad.numpy() & 2).any()):  # a doubt on sigma or delta
            A.check_at_least("sigma", s, 0.0)
            A.check_at_least("delta", d, 0.0)
    else:
        _launch(a, _FORWARD[a.scalar], n_rays,
                [s, _vec_view(c, 3), d, zz, offsets, bg, per_ray, a.s(t_threshold), res.rgb, res.depth,
                 res.opacity, res.transmittance, res.n_used, factor, factor_given, _vec_view(factor, 4),
                 _vec_view(zz, 4), int(check), bad], min_chunk=_min_chunk(n_rays, n))
    if check and n_rays and (bad.numpy() & 1).any():  # a NaN or inf in rgb or z, or a false alarm (module docstring)
        A.check_finite("rgb", c)
        A.check_finite("z", zz)
    if out is not None or not a.as_numpy:
        return res
    return CompositeResult(**{k: None if v is None else a.out(v) for k, v in vars(res).items()})


def composite_backward(
    sigma: A.ArrayLike,
    rgb: A.ArrayLike,
    delta: A.ArrayLike,
    z: A.ArrayLike,
    ray_offsets: A.ArrayLike,
    result: CompositeResult,
    grad_rgb: A.ArrayLike | None = None,
    grad_depth: A.ArrayLike | None = None,
    grad_opacity: A.ArrayLike | None = None,
    background: Any = (0.0, 0.0, 0.0),
    device: str | wp.Device | None = None,
    out: tuple[wp.array, wp.array] | None = None,
) -> tuple[A.ArrayLike, A.ArrayLike]:
    """Gradients (d sigma (N,), d rgb (N, 3)) of <grad_rgb, C> + <grad_depth, D> + <grad_opacity, A>.

    Returns the pair in the kind of `sigma` (NumPy arrays, or wp.arrays on the device). `result`
    is what `composite_forward` returned for the same inputs and background (NumPy or wp.arrays);
    missing cotangents count as zero. Shapes and dtypes are checked again, the sample values are
    not (composite_forward checked them, and stored in `result` what the backward needs of
    sigma); the cotangents' are. `out`, if given, is the pair of wp.array buffers (N,) and (N, 3)
    to write the gradients into (and is returned); every entry is written.
    """
    if not isinstance(result, CompositeResult):
        raise ValueError(f"result: expected the CompositeResult of composite_forward, got {type(result).__name__}")
    check_backpropagatable("result", result)
    a = A.Inputs(device, sigma, rgb, delta, z, ray_offsets)
    (_, c, d, zz, offsets), n, n_rays = _samples(a, sigma, rgb, delta, z, ray_offsets, values=False)
    layout = _result_layout(n_rays, n, a.scalar)
    res = {}
    for k in ("factor", "rgb", "depth", "transmittance", "n_used"):
        shape, t = layout[k]
        x = getattr(result, k)
        res[k] = (a.ints(f"result.{k}", x, shape) if t == wp.int32
                  else a.floats(f"result.{k}", x, shape, finite=False))  # factor: entries past termination unset
    bg, per_ray = _background(a, background, n_rays)
    grads = [a.floats_or_zeros("grad_rgb", grad_rgb, (n_rays, 3)),
             a.floats_or_zeros("grad_depth", grad_depth, (n_rays,)),
             a.floats_or_zeros("grad_opacity", grad_opacity, (n_rays,))]
    if out is None:
        grad_sigma, grad_sample_rgb = a.empty(n), a.empty((n, 3))
    else:
        if not isinstance(out, (tuple, list)) or len(out) != 2:
            raise ValueError("out: expected a pair (grad_sigma (N,), grad_rgb (N, 3)) of wp.arrays")
        grad_sigma = A.check_out("out[0]", out[0], (n,), a.scalar, a.device)
        grad_sample_rgb = A.check_out("out[1]", out[1], (n, 3), a.scalar, a.device)
    simd = (_host_passes(a.device) and a.scalar == wp.float32 and SIMD_BACKWARD and 3 * n < 2**31
            and all(x.is_contiguous for x in (res["factor"], c, d, zz, offsets, grad_sigma, grad_sample_rgb)))
    if simd:  # CPU, float32: eight rays a thread in vector lanes, bit for bit the Warp kernel (composite_cpu)
        _launch(a, composite_cpu.backward_kernel(), (n_rays + composite_cpu.LANES - 1) // composite_cpu.LANES,
                [res["factor"], c, d, zz, offsets, bg, per_ray, res["rgb"], res["depth"], res["transmittance"],
                 res["n_used"], *grads, grad_sigma, grad_sample_rgb],
                min_chunk=max(1, _min_chunk(n_rays, n) // composite_cpu.LANES))
    else:
        _launch(a, _BACKWARD[a.scalar], n_rays,
                [res["factor"], _vec_view(c, 3), d, zz, offsets, bg, per_ray, res["rgb"], res["depth"],
                 res["transmittance"], res["n_used"], *grads, grad_sigma, _vec_view(grad_sample_rgb, 3),
                 _vec_view(res["factor"], 4), _vec_view(zz, 4), _vec_view(d, 4), _vec_view(grad_sigma, 4)],
                min_chunk=_min_chunk(n_rays, n))
    if out is not None:
        return grad_sigma, grad_sample_rgb
    return a.out(grad_sigma), a.out(grad_sample_rgb)


def _vec_view(x: wp.array, length: int) -> wp.array:
    """A contiguous float array seen as consecutive vectors of `length` (x[length i : length (i+1)] as entry i;
    a trailing remainder is left out). Zero-copy: x must stay alive while the view is used."""
    vt = (_VEC3 if length == 3 else _VEC4)[x.dtype]
    return wp.array(ptr=x.ptr, dtype=vt, shape=(x.size // length,), device=x.device)
