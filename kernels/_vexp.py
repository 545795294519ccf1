"""A float32 exp on 16 SIMD lanes with the bits of glibc's expf (what wp.exp calls on the CPU): the C++ in
kernels/native/vexp16.h (clang vector extensions), included by the wp.func_native snippets of kernels.splat.rowblend
and kernels.stereo.adcensus; this module holds the check against the C library's expf.

vexp16.h computes e = exp(xin) in the lanes of the mask `run` (v16i, -1 where running) from `power` (v16f), as glibc's
expf (2.27 and later, the variant for CPUs with FMA, __expf_fma) in float64 lanes: z = x N / ln 2 (N = 32),
k = round(z) by adding and subtracting SHIFT = 1.5 * 2^52, r = z - k, 2^(k/N) from the table T[k mod N] = 2^(j/N)
plus k's high bits in the exponent field, exp(x) ~ (C0 r^3 + C1 r^2 + C2 r + 1) 2^(k/N), with glibc's fused products
fma(N / ln 2, x, SHIFT), fma(N / ln 2, x, -k), fma(fma(C0, r, C1), r^2, fma(C2, r, 1)), then one rounding to
float32: the bits of expf for every float32 (all 2^32 inputs were checked once with exp16_mismatches; tests sweep a
sample). Lanes outside that fast path (|x| >= 88, infinite or NaN) make the whole vector call expf itself, lane by
lane; lanes not running get x = 0. vexp_types.h declares the vector types (v16f, v16i, v8f, v8d, v8l) and the
table TAB; a snippet includes vexp_types.h, sets `power` and `run`, then includes vexp16.h. Only for code compiled
where the CPU has AVX2 and FMA (guard with `#if defined(__CUDA_ARCH__) || !defined(__AVX2__) ||
!defined(__FMA__)`: there glibc runs __expf_fma). A C library whose expf is another algorithm (glibc before 2.27, musl) would make the bits differ from
wp.exp's: exp16_mismatches says so.
"""

from __future__ import annotations

import warp as wp

from kernels.native import source


# For tests: how many of the 16 floats with bits lo + (16 b + l) stride (l < 16, the first n) get other
# bits from the lanes' exp than from the C library's expf (what wp.exp calls).
@wp.func_native(source("vexp_mismatches.cpp"))
def exp16_mismatches(lo: wp.uint32, stride: wp.uint32, b: int, n: int) -> int: ...

