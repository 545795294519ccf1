"""One splat blended into one 16-pixel row of a tile, 16 pixels at once (float32, CPU): the
rasteriser's per-pixel step (kernels/splat/raster.py) in SIMD lanes, with the same bits. The C++ is in
kernels/native/rowblend.cpp (with the shared lanes.h and kernels._vexp's vexp16.h), loaded by
`kernels.native.source`.

For the pixels px of the row still running (bit px - x_lo of `live`) and inside the splat's columns,
each lane computes what the scalar loop computes, operation for operation in float32 (no fused
multiply-adds: every product and sum is its own statement):

    dx = u - (px + 1/2),  power = (-1/2)((qa dx) dx + (qc dy) dy) - (qb dx) dy
    skipped if power > 0 or power < thr;  alpha = min(alpha_max, o exp(power)) (Warp's min:
    alpha_max unless o exp(power) < alpha_max, NaN included);  skipped if alpha < 1/255
    next_T = T (1 - alpha): below t_stop the pixel stops (its bit cleared, nothing blended), else
    w = alpha T;  rgb += w colour, depth += w z (each w c rounded, then the sum), T = next_T,
    n_contrib = s + 1.

exp (kernels._vexp) is glibc's expf (2.27 and later, the variant for CPUs with FMA, __expf_fma) in float64 lanes:
z = x N / ln 2 (N = 32), k = round(z) by adding and subtracting SHIFT = 1.5 * 2^52,
r = z - k, 2^(k/N) from the table T[k mod N] = 2^(j/N) plus k's high bits in the exponent field,
exp(x) ~ (C0 r^3 + C1 r^2 + C2 r + 1) 2^(k/N), with glibc's fused products
fma(N / ln 2, x, SHIFT), fma(N / ln 2, x, -k), fma(fma(C0, r, C1), r^2, fma(C2, r, 1)), then one
rounding to float32: the bits of expf for every float32 (all 2^32 inputs were checked once with
exp16_mismatches; tests/kernels/test_splat_rowblend.py sweeps a sample). A row where a running lane's power has
|power| >= 88, is infinite or NaN (outside that fast path; the rasteriser's powers lie in
[-ln 255, 0]) calls expf itself, lane by lane. Compiled only where the CPU has AVX2 and FMA
(__AVX2__, __FMA__: there glibc runs __expf_fma); elsewhere `rowblend_available()` is False and the
rasteriser keeps its scalar loop. A C library whose expf is another algorithm (glibc before 2.27,
musl) would make the bits differ from wp.exp's: test_row_blend_exp_is_expf says so.

The tile's per-pixel state lives in `state` (n_tiles, 5 * 256: planes T, r, g, b, depth, each 16 x
16, row-major) and `nc` (n_tiles, 256); `live` (n_tiles, 16) holds each row's running-pixel bits.
Returns how many pixels stopped.
"""

from __future__ import annotations

import warp as wp

from kernels.native import native_flag, source
from kernels._vexp import exp16_mismatches  # noqa: F401  (tests import it from here)

@wp.func_native(source("rowblend.cpp"))
def blend_row(state: wp.array2d(dtype=wp.float32), nc: wp.array2d(dtype=wp.int32), live: wp.array2d(dtype=wp.int32),
              tile: int, row: int, cols: int, x_lo: int, dy: wp.float32, u: wp.float32, qa: wp.float32,
              qb: wp.float32, qc: wp.float32, o: wp.float32, thr: wp.float32, z: wp.float32, c0: wp.float32,
              c1: wp.float32, c2: wp.float32, alpha_max: wp.float32, t_stop: wp.float32, s1: int) -> int: ...



@wp.func_native(source("rowblend_available.cpp"))
def _rowblend_available() -> int: ...


def rowblend_available() -> bool:
    """Whether the CPU kernels were compiled with AVX2 and FMA (blend_row is active)."""
    return native_flag(_rowblend_available) == 1
