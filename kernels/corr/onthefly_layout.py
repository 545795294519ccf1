"""The on-the-fly lookup's host-side layout: channels-last copies, full-product levels by BLAS, pixel groups.

Features are kept channels-last, (C, N) -> (N, ceil(C / 8)) vectors of 8 (channels zero-padded),
so that a tap's dot product f1[:, p] . P^l(f2)[:, q] is a few vector multiply-adds; `_rows` views
them as (N, C8) scalar rows for the C++ kernels.

Full-product levels (few pixels: 2 H_l W_l <= (2r + 2)^2, `_common.full_product_level`) take every
tap from the rows of

    V^l = f1^T P^l(f2) / sqrt(C)   ((N, H_l W_l), formed by BLAS in 256-row products)

instead of patches (the scale on the small operand first, `_scaled_level`), then sample them as the
dense lookup samples V^l (`_sample_full_product`). The row chunks are the same whatever the thread
count, so the values do not depend on it.

The pixel grouping of the C++ patches (`_group_pixels`: pixels grouped by their window's column
origin, `patch_cpu.group_pixels_cpu`) and its arrays, and the slot launches of the backward's
scatter (`_launch_slots`: chunk s of the pixels on its own thread, adding into slot s) are here too.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable

import numpy as np
import warp as wp

from kernels import fast_paths
from kernels._arrays import Inputs
from kernels.corr import patch_cpu, window_cpu
from kernels.corr._common import VEC, VEC_OF, pack_rows
from kernels.corr.onthefly_kernels import _unpack_channels_last_v
from kernels.launch import chunk_bounds, parallel_ranges


def _channels_last_v(x: wp.array, a: Inputs) -> wp.array:
    """(C, N) scalars -> (N, ceil(C / 8)) vectors.

    On the CPU with C a multiple of 8 the vectors are the rows of x^T itself: NumPy's transposed
    copy, aliased as vectors (a quarter of the packing kernel's time, which reads x^T strided).
    """
    channels, n = x.shape
    if fast_paths.on(a.device) and channels % VEC == 0:
        rows = np.ascontiguousarray(x.numpy().T).reshape(n, channels // VEC, VEC)
        return wp.array(rows, dtype=VEC_OF[a.scalar], device=a.device, copy=False)  # keeps `rows` alive
    return pack_rows(x.transpose(), -(-channels // VEC), a)


def _channels_last_later(x: wp.array, a: Inputs) -> tuple[wp.array, Callable[[int, int], None]]:
    """(C, N) scalars (C a multiple of 8, CPU) -> the (N, C / 8) vectors of `_channels_last_v`, allocated
    here and filled by `fill(lo, hi)` row range by row range (the same values; NumPy copies without the GIL)."""
    channels, n = x.shape
    out_v = a.empty((n, channels // VEC), VEC_OF[a.scalar])
    src, dst = x.numpy(), out_v.numpy().reshape(n, channels)

    def fill(lo: int, hi: int) -> None:
        np.copyto(dst[lo:hi], src[:, lo:hi].T)

    return out_v, fill


_blas_controller = None
_BLAS_ROWS = 256  # rows of V^l per BLAS call in `_sample_full_product`


def _one_blas_thread() -> Any:
    """A context in which BLAS runs on the calling thread alone (threadpoolctl; process-wide while it lasts).

    The full products are split by rows over the launch threads (`parallel_ranges`), one BLAS thread
    each: OpenBLAS's own threads spin on cores the launch threads already use (measured on the busy
    2-core host: the on-the-fly forward took 36 ms of CPU time with them, 22 ms with one BLAS
    thread per launch thread).
    """
    global _blas_controller
    if _blas_controller is None:
        from threadpoolctl import ThreadpoolController

        _blas_controller = ThreadpoolController()
    return _blas_controller.limit(limits=1, user_api="blas")


def _sample_full_product(x1_rows: np.ndarray, f2s: np.ndarray, height_l: int, width_l: int, xy: wp.array,
                         out: wp.array, lvl: int, radius: int, scratch: wp.array, a: Inputs) -> None:
    """Level `lvl` of (4) from V^l = f1^T P^l(f2) / sqrt(C), formed by BLAS.

    x1_rows: f1 channels-last (N, C) on the host; f2s: P^l(f2) / sqrt(C) as (C, H_l W_l), C-ordered
    (`_scaled_level`). The rows of V^l ((N, H_l W_l), in the memory of `scratch`, the patch buffer:
    a full-product level holds at most half a patch's taps, `full_product_level`) are formed, then
    sampled like a dense level.
    """
    n = x1_rows.shape[0]
    taps = height_l * width_l
    if n * taps > scratch.size:
        raise AssertionError(f"full-product level of {taps} taps a pixel exceeds the patch buffer")
    flat = scratch.numpy().reshape(-1)[:n * taps].reshape(n, taps)
    buf = wp.array(flat.reshape(n, height_l, width_l), dtype=a.scalar, device=a.device, copy=False)
    side = 2 * radius + 1
    starts = range(0, n, _BLAS_ROWS)

    def products(lo: int, hi: int) -> None:
        # The same BLAS calls (row chunks of _BLAS_ROWS) whatever the thread count, so the
        # values do not depend on it (BLAS may round a product's edge rows differently).
        for r0 in starts[lo:hi]:
            r1 = min(r0 + _BLAS_ROWS, n)
            np.matmul(x1_rows[r0:r1], f2s, out=flat[r0:r1])

    with _one_blas_thread():
        parallel_ranges(products, len(starts), min_chunk=1)
    # `sample_windows`' windows (full products are CPU-only), bit for bit: the dense lookup's C++
    # kernel on this one level
    a.launch(window_cpu.sample_levels_cpu(radius, a.scalar), window_cpu.blocks(n),
             [buf, buf, buf, buf, 1, xy, out, a.s(0.5 ** lvl), lvl * side * side], min_chunk=64)


def _channels_first(x_v: wp.array, channels: int, a: Inputs) -> wp.array:
    out = a.zeros((channels, x_v.shape[0]))
    a.launch(_unpack_channels_last_v, out.size, [x_v, out])
    return out


def _launch_slots(kernel: Any, dim: int, inputs: list[Any], n_slots: int, device: wp.Device) -> None:
    """Chunk s of [0, dim) launched on its own thread with `slot = s` (kernel params end `slot, offset`).

    A CPU launch runs on one thread and releases the GIL (docs/warp.md), so the chunks run in parallel,
    each adding into its own slot; on CUDA one launch covers all of [0, dim) in slot 0.
    """
    if device.is_cuda or n_slots == 1:
        wp.launch(kernel, dim=dim, inputs=[*inputs, 0, 0], device=device)
        return
    bounds = chunk_bounds(dim, n_slots)
    with ThreadPoolExecutor(max_workers=n_slots - 1) as pool:
        futures = [pool.submit(wp.launch, kernel, dim=size, inputs=[*inputs, s, off], device=device)
                   for s, (off, size) in enumerate(bounds[1:], start=1)]
        off, size = bounds[0]
        wp.launch(kernel, dim=size, inputs=[*inputs, 0, off], device=device)
        for fut in futures:
            fut.result()



def _scaled_level(level_rows: np.ndarray, channels: int, inv: float, a: Inputs) -> np.ndarray:
    """P^l(f2) / sqrt(C) as a C-ordered (C, H_l W_l) array from its channels-last rows (N_l, >= C).
    The scale goes on the small operand first, as in `volume._gemm_blas` (exact when sqrt(C) is a
    power of two)."""
    f2s = np.empty((channels, level_rows.shape[0]), dtype=a.np_dtype)
    f2s[...] = level_rows[:, :channels].T
    f2s *= a.np_dtype.type(inv)
    return f2s


def _rows(x_v: wp.array) -> wp.array:
    """Channels-last vectors (N, C8 / 8) viewed as their rows of scalars (N, C8) (no copy; x_v outlives the view)."""
    n, n_vec = x_v.shape
    return wp.array(ptr=x_v.ptr, shape=(n, n_vec * VEC), dtype=x_v.dtype._wp_scalar_type_, device=x_v.device)



def _grouping_arrays(a: Inputs, n: int, radius: int, height_l: int,
                     width_l: int) -> tuple[int, list[wp.array], wp.array, wp.array]:
    """(number of groups, [i0, j0, order, sorted j0] (N,), starts, counts): `group_pixels_cpu`'s outputs and scratch."""
    side = 2 * radius + 2
    n_groups = width_l + side + 1
    ints = [a.empty(n, wp.int32) for _ in range(4)]
    return n_groups, ints, a.empty(n_groups + 1, wp.int32), a.empty(n_groups * (height_l + side + 1) + 1, wp.int32)


def _group_pixels(a: Inputs, xy: wp.array, scale: Any, radius: int, height_l: int,
                  width_l: int) -> tuple[int, wp.array, wp.array, wp.array]:
    """The pixels grouped for `patch_cpu.patch_groups_cpu` at one level (`patch_cpu.group_pixels_cpu`):
    (number of groups, pixel order, each ordered pixel's window row origin, each group's first position)."""
    n_groups, ints, starts, counts = _grouping_arrays(a, xy.shape[1] * xy.shape[2], radius, height_l, width_l)
    a.launch(patch_cpu.group_pixels_cpu(radius, a.scalar), 1, [xy, scale, *ints, starts, counts, height_l, width_l])
    return n_groups, ints[2], ints[3], starts
