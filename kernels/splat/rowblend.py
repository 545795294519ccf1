"""One splat blended into one 16-pixel row of a tile, 16 pixels at once (float32, CPU): the
rasteriser's per-pixel step (kernels/splat/raster.py) in SIMD lanes, with the same bits.

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

from kernels._native import SELECT_CPP
from kernels._vexp import EXP16 as _EXP16
from kernels._vexp import TYPES as _TYPES
from kernels._vexp import exp16_mismatches  # noqa: F401  (tests import it from here)

_SNIPPET = r"""
#if defined(__CUDA_ARCH__) || !defined(__AVX2__) || !defined(__FMA__)
    return 0;
#else
""" + _TYPES + SELECT_CPP + r"""
    int* live_row = (int*)((char*)live.data + (size_t)tile * live.strides[0]) + row;
    const int todo = live_row[0] & cols;
    if (todo == 0)
        return 0;
    char* st = (char*)state.data + (size_t)tile * state.strides[0];
    float* pT = (float*)st + row * 16;
    float* pR = pT + 256;
    float* pG = pT + 512;
    float* pB = pT + 768;
    float* pD = pT + 1024;
    int* pN = (int*)((char*)nc.data + (size_t)tile * nc.strides[0]) + row * 16;
    const v16i lane = {1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024, 2048, 4096, 8192, 16384, 32768};
    const v16f offs = {0.f, 1.f, 2.f, 3.f, 4.f, 5.f, 6.f, 7.f, 8.f, 9.f, 10.f, 11.f, 12.f, 13.f, 14.f, 15.f};
    const v16i act = (lane & todo) != 0;
    // px + 1/2 for px = x_lo + lane, exact: (float)x_lo + lane is (float)(x_lo + lane) below 2^24
    const v16f pxi = (float)x_lo + offs;
    const v16f pxf = pxi + 0.5f;
    const v16f dx = u - pxf;
    const float neg_half = -0.5f;
    const float ty1 = qc * dy;
    const float ty2 = ty1 * dy;
    v16f t1 = qa * dx;
    t1 = t1 * dx;
    const v16f t2 = t1 + ty2;
    const v16f t3 = neg_half * t2;
    v16f t4 = qb * dx;
    t4 = t4 * dy;
    const v16f power = t3 - t4;
    v16i run = act & ~((power > 0.0f) | (power < thr));
    if (!__builtin_reduce_or(run))
        return 0;
""" + _EXP16 + r"""
    const v16f oe = o * e;
    const v16f amax = alpha_max;
    // Warp's min(alpha_max, x): alpha_max if alpha_max <= x, else x unless x is NaN
    const v16i take_max = (amax <= oe) | (oe != oe);
    const v16f alpha = sel(take_max, amax, oe);
    run = run & ~(alpha < (float)(1.0 / 255.0));
    v16f T, R, G, B, D;
    v16i N;
    __builtin_memcpy(&T, pT, 64);
    const v16f one16 = 1.0f;
    const v16f om = one16 - alpha;
    const v16f next_t = T * om;
    const v16i stop = run & (next_t < t_stop);
    const v16i blend = run & ~stop;
    int n_stop = 0;
    if (__builtin_reduce_or(stop)) {
        int cleared = 0;
        for (int l = 0; l < 16; ++l)
            if (stop[l]) {
                cleared |= 1 << l;
                ++n_stop;
            }
        live_row[0] = live_row[0] & ~cleared;
    }
    if (!__builtin_reduce_or(blend))
        return n_stop;
    __builtin_memcpy(&R, pR, 64);
    __builtin_memcpy(&G, pG, 64);
    __builtin_memcpy(&B, pB, 64);
    __builtin_memcpy(&D, pD, 64);
    __builtin_memcpy(&N, pN, 64);
    const v16f w = alpha * T;
    const v16f wr = w * c0;
    const v16f wg = w * c1;
    const v16f wb = w * c2;
    const v16f wd = w * z;
    const v16f R2 = R + wr;
    const v16f G2 = G + wg;
    const v16f B2 = B + wb;
    const v16f D2 = D + wd;
    R = sel(blend, R2, R);
    G = sel(blend, G2, G);
    B = sel(blend, B2, B);
    D = sel(blend, D2, D);
    T = sel(blend, next_t, T);
    const v16i s16 = s1;
    N = sel(blend, s16, N);
    __builtin_memcpy(pT, &T, 64);
    __builtin_memcpy(pR, &R, 64);
    __builtin_memcpy(pG, &G, 64);
    __builtin_memcpy(pB, &B, 64);
    __builtin_memcpy(pD, &D, 64);
    __builtin_memcpy(pN, &N, 64);
    return n_stop;
#endif
"""

_AVAILABLE = r"""
#if defined(__CUDA_ARCH__) || !defined(__AVX2__) || !defined(__FMA__)
    return 0;
#else
    return 1;
#endif
"""


@wp.func_native(_SNIPPET)
def blend_row(state: wp.array2d(dtype=wp.float32), nc: wp.array2d(dtype=wp.int32), live: wp.array2d(dtype=wp.int32),
              tile: int, row: int, cols: int, x_lo: int, dy: wp.float32, u: wp.float32, qa: wp.float32,
              qb: wp.float32, qc: wp.float32, o: wp.float32, thr: wp.float32, z: wp.float32, c0: wp.float32,
              c1: wp.float32, c2: wp.float32, alpha_max: wp.float32, t_stop: wp.float32, s1: int) -> int: ...



@wp.func_native(_AVAILABLE)
def _rowblend_available() -> int: ...


@wp.kernel(enable_backward=False)
def _available_kernel(out: wp.array(dtype=wp.int32)):
    out[0] = _rowblend_available()


def rowblend_available() -> bool:
    """Whether the CPU kernels were compiled with AVX2 and FMA (blend_row is active)."""
    out = wp.zeros(1, dtype=wp.int32, device="cpu")
    wp.launch(_available_kernel, 1, [out], device="cpu")
    return bool(out.numpy()[0])
