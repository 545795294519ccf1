"""The compositing forward and backward on the CPU in C++, eight rays at once in vector lanes (float32).

The C++ is in kernels/native/composite_forward.cpp and composite_backward.cpp (with the shared
lanes.h, blend8.h, transpose8.h and kernels._npexp's npexp16.h), loaded by `kernels.native.source`.

The same quadrature as `composite_kernels._composite_forward_kernel` (its module docstring), with the
factors e_k = exp(-sigma_k delta_k) given (NumPy's pass filled them), or, with `fused`, evaluated
here: a group's samples [o_{r0}, o_{r0+8}) are contiguous, and 16 at a time each gets
e_k = exp(-(sigma_k delta_k)) (the product rounded, then negated, as NumPy's pass computes it) with
NumPy's float32 exp reproduced bit for bit (kernels._npexp), into one slot of a two-slot ring on
the thread's stack (RING samples a slot), from which the steps read them back; with keep = 1 also
into `factor` (every sample, past termination too, as the pass does), by non-temporal 64-byte
stores where aligned, so that the N-sized array streams out without being read for ownership;
with keep = 0 `factor` is neither read nor written. A group of more than RING samples (keep = 1
only: composite.py sends keep = 0 calls with such groups to keep = 1 with a scratch array) has its
factors filled into `factor` alone and read back from there. With the value check, one
unsigned maximum of the bits of sigma and delta flags the group's rays with 2 in out_bad
(composite.py then runs the exact checks). A forward thread takes GROUPS groups one after the
other: the first group's factors are filled before its steps, each later group's 16 a step during
the steps of the group before it (the rest after them), so that this stream of sigma and delta
overlaps the gathers. For each ray the same float32 operations in the same
order, so the same outputs bit for bit. Lane l of a group runs
ray r = r0 + l; at step i every lane still running takes its sample k = o_r + i:

    run  = i < n_r  and  not (T < t_threshold)           (early termination before sample k)
    w = T (1 - e_k);  T' = T e_k;  C' = C + w c_k (each channel);  D' = D + w z_k
    n_used = the number of steps the lane ran

each product and each sum its own statement and floating-point contraction off, so no fused
multiply-add appears (none does in Warp's generated code either). Lanes that have ended keep their
values (a select by the run mask); what they read (their factor replaced by 1) nothing uses. The
step count is the longest ray of the group: the sample indices are o_r + i whatever the lanes'
transmittances, so the loads do not wait on the recurrence. With `fused` (offsets covering the N
samples, non-decreasing) the steps go in blocks of eight: each lane loads samples o_r + i0 ..
o_r + i0 + 7 of every array as one unaligned vector (three for the interleaved colours), element
by element where that would pass the group's last sample, and 8 x 8 register transposes give the
eight steps' lane vectors (5 transposes of 24 shuffles against 40 gathers of 8); without it each
step gathers its sample, clamped to N - 1. The
optional value check adds up, per lane after the loop, the colours and depths of the samples
after early termination exactly as the Warp kernel does, and flags the ray when any sum is NaN or
infinite. Rays past the last of a group of eight get no lanes' results written.

The backward (`composite._composite_backward_kernel`) the same way: per lane, the ray's cotangents,
total = g_C . (C - T_N b) + g_D D and tail = T_N (g_A - g_C . b) in scalar code as the Warp kernel
computes them; then at step i every lane with i < n_used (nothing depends on the transmittance
here) takes its sample k = o_r + i:

    w = T (1 - e_k);  f = ((g_r c_r + g_g c_g) + g_b c_b) + g_D z_k;  prefix' = prefix + w f
    T' = T e_k;  dL/dsigma_k = delta_k ((T' f - (total - prefix')) + tail);  dL/dc_k = g_C w

and stores its two gradients; the samples after n_used get zeros. The steps go in blocks of eight as
in the fused forward (each lane's eight samples of F, z, delta and the colours as row vectors, element
by element clamped to N - 1 where a row would pass N, and 8 x 8 register transposes); the eight steps'
gradient columns are transposed back into rows, stored as vectors where the lane runs all eight
steps, element by element up to n_used otherwise. Both kernels
prefetch the next group's samples (its gradients too, in the backward) over the steps of the
current group: eight rays in lanes read eight streams, which the hardware prefetcher alone served
more slowly than the Warp kernel's one stream (in DRAM, without this, the backward was slower than
the Warp kernel and the forward no faster). The fused forward's factor loop reads sigma and delta
as two contiguous streams, left to the hardware prefetcher (prefetching them too was slower).

Why. The Warp kernel runs one ray per thread: its loop-carried product T e_k and the scalar loads
cost ~3.1-3.3 ns a sample on a core (docs/performance.md, "CPU fast paths", has what the lanes gain), and Warp has
no way to put several rays in SIMD lanes. `forward_kernel()` and `backward_kernel()` are launched on
the CPU only, for float32 and contiguous sample arrays; float64 and CUDA keep the Warp kernels.
"""

from typing import Any

import warp as wp

from kernels.native import built_once, source

LANES = 8  # rays in the lanes of a group
GROUPS = 8  # groups of LANES rays per thread of the forward kernel
RING = 2048  # samples a slot of the forward's two-slot factor ring (keep=0): 8 KB of float32, a slot

_kernels: dict = {}


def forward_kernel() -> Any:
    """The C++ forward kernel (float32; module docstring), built once."""
    return built_once(_kernels, "forward", _build)


def backward_kernel() -> Any:
    """The C++ backward kernel (float32; module docstring), built once."""
    return built_once(_kernels, "backward", _build_backward)


def _build_backward() -> Any:
    f32 = wp.array(dtype=wp.float32)
    f32_2 = wp.array2d(dtype=wp.float32)
    i32 = wp.array(dtype=wp.int32)

    def composite_grads8_cpu(factor: f32, rgb: f32_2, delta: f32, z: f32, offsets: i32, background: f32_2,
                             per_ray: int, out_rgb: f32_2, out_depth: f32, out_transmittance: f32, out_n_used: i32,
                             grad_rgb: f32_2, grad_depth: f32, grad_opacity: f32, grad_sigma: f32,
                             grad_sample_rgb: f32_2, r0: int): ...

    native = wp.func_native(source("composite_backward.cpp"))(composite_grads8_cpu)

    @wp.kernel(module="unique", module_options={"enable_backward": False})
    def composite_backward_cpu(factor: f32, rgb: f32_2, delta: f32, z: f32, offsets: i32, background: f32_2,
                               per_ray: int, out_rgb: f32_2, out_depth: f32, out_transmittance: f32,
                               out_n_used: i32, grad_rgb: f32_2, grad_depth: f32, grad_opacity: f32,
                               grad_sigma: f32, grad_sample_rgb: f32_2, offset: int):
        # thread g = rays 8 g .. 8 g + 7
        g = wp.tid() + offset
        native(factor, rgb, delta, z, offsets, background, per_ray, out_rgb, out_depth, out_transmittance,
               out_n_used, grad_rgb, grad_depth, grad_opacity, grad_sigma, grad_sample_rgb, g * 8)

    return composite_backward_cpu


def _build() -> Any:
    f32 = wp.array(dtype=wp.float32)
    f32_2 = wp.array2d(dtype=wp.float32)
    i32 = wp.array(dtype=wp.int32)

    def composite_rays8_cpu(sigma: f32, delta: f32, fused: int, keep: int, factor: f32, rgb: f32_2, z: f32, offsets: i32, background: f32_2, per_ray: int,
                            t_threshold: wp.float32, out_rgb: f32_2, out_depth: f32, out_opacity: f32,
                            out_transmittance: f32, out_n_used: i32, check_values: int, out_bad: i32,
                            grp: int): ...

    native = wp.func_native(source("composite_forward.cpp", GROUPS=GROUPS, RING=RING))(composite_rays8_cpu)

    @wp.kernel(module="unique", module_options={"enable_backward": False})
    def composite_forward_cpu(sigma: f32, delta: f32, fused: int, keep: int, factor: f32, rgb: f32_2, z: f32, offsets: i32, background: f32_2, per_ray: int,
                              t_threshold: wp.float32, out_rgb: f32_2, out_depth: f32, out_opacity: f32,
                              out_transmittance: f32, out_n_used: i32, check_values: int, out_bad: i32,
                              offset: int):
        # thread g = rays 8 GROUPS g .. 8 GROUPS (g + 1) - 1
        g = wp.tid() + offset
        native(sigma, delta, fused, keep, factor, rgb, z, offsets, background, per_ray, t_threshold, out_rgb, out_depth, out_opacity,
               out_transmittance, out_n_used, check_values, out_bad, g)

    return composite_forward_cpu
