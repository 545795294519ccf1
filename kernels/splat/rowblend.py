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

exp is glibc's expf (2.27 and later, the variant for CPUs with FMA, __expf_fma) in float64 lanes:
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

# Vector types and glibc's table 2^(j/32) (__exp2f_data.tab: bits of 2^(j/32) less j << 47).
_TYPES = r"""
    typedef float v16f __attribute__((ext_vector_type(16)));
    typedef int v16i __attribute__((ext_vector_type(16)));
    typedef float v8f __attribute__((ext_vector_type(8)));
    typedef double v8d __attribute__((ext_vector_type(8)));
    typedef long long v8l __attribute__((ext_vector_type(8)));
    static const unsigned long long TAB[32] = {
        0x3ff0000000000000ULL, 0x3fefd9b0d3158574ULL, 0x3fefb5586cf9890fULL, 0x3fef9301d0125b51ULL,
        0x3fef72b83c7d517bULL, 0x3fef54873168b9aaULL, 0x3fef387a6e756238ULL, 0x3fef1e9df51fdee1ULL,
        0x3fef06fe0a31b715ULL, 0x3feef1a7373aa9cbULL, 0x3feedea64c123422ULL, 0x3feece086061892dULL,
        0x3feebfdad5362a27ULL, 0x3feeb42b569d4f82ULL, 0x3feeab07dd485429ULL, 0x3feea47eb03a5585ULL,
        0x3feea09e667f3bcdULL, 0x3fee9f75e8ec5f74ULL, 0x3feea11473eb0187ULL, 0x3feea589994cce13ULL,
        0x3feeace5422aa0dbULL, 0x3feeb737b0cdc5e5ULL, 0x3feec49182a3f090ULL, 0x3feed503b23e255dULL,
        0x3feee89f995ad3adULL, 0x3feeff76f2fb5e47ULL, 0x3fef199bdd85529cULL, 0x3fef3720dcef9069ULL,
        0x3fef5818dcfba487ULL, 0x3fef7c97337b9b5fULL, 0x3fefa4afa2a490daULL, 0x3fefd0765b6e4540ULL};
"""

# e = exp(xin) in the lanes of `run` (glibc's expf; lanes outside its fast path call expf itself).
_EXP16 = r"""
    // exp: glibc's fast path; lanes outside it (|x| >= 88, inf, NaN) call expf
    // lanes not running get x = 0 (their garbage powers could make denormals: slow, and unused)
    const v16f xin = __builtin_bit_cast(v16f, run & __builtin_bit_cast(v16i, power));
    const v16i bits = __builtin_bit_cast(v16i, xin);
    const v16i outside = run & (((bits >> 20) & 0x7ff) > 0x42a);
    v16f e;
    if (__builtin_reduce_or(outside)) {
        // through a volatile pointer: the compiler must not turn these calls into a vector libm's
        typedef __typeof__(::expf)* expf_fn;
        expf_fn volatile libm_expf = &::expf;
        for (int l = 0; l < 16; ++l)
            e[l] = run[l] ? libm_expf(xin[l]) : 0.0f;
    } else {
        const double inv_ln2_n = 0x1.71547652b82fep+5;
        const double shift = 0x1.8p+52;
        v8f yh[2];
        for (int h = 0; h < 2; ++h) {
            const v8f xf = h == 0 ? __builtin_shufflevector(xin, xin, 0, 1, 2, 3, 4, 5, 6, 7)
                                  : __builtin_shufflevector(xin, xin, 8, 9, 10, 11, 12, 13, 14, 15);
            const v8d xd = __builtin_convertvector(xf, v8d);
            v8d kd = __builtin_elementwise_fma((v8d)inv_ln2_n, xd, (v8d)shift);
            const v8l ki = __builtin_bit_cast(v8l, kd);
            kd = kd - shift;
            const v8d r = __builtin_elementwise_fma((v8d)inv_ln2_n, xd, -kd);
            v8l tb;
            for (int l = 0; l < 8; ++l)
                tb[l] = (long long)TAB[ki[l] & 31];
            const v8d s = __builtin_bit_cast(v8d, tb + (ki << 47));
            const v8d p = __builtin_elementwise_fma((v8d)0x1.c6af84b912394p-20, r, (v8d)0x1.ebfce50fac4f3p-13);
            const v8d r2 = r * r;
            const v8d q = __builtin_elementwise_fma(r, (v8d)0x1.62e42ff0c52d6p-6, (v8d)1.0);
            const v8d y = __builtin_elementwise_fma(p, r2, q);
            const v8d ys = y * s;
            yh[h] = __builtin_convertvector(ys, v8f);
        }
        e = __builtin_shufflevector(yh[0], yh[1], 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    }
"""

_SNIPPET = r"""
#if defined(__CUDA_ARCH__) || !defined(__AVX2__) || !defined(__FMA__)
    return 0;
#else
""" + _TYPES + r"""
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
    const v16f alpha = __builtin_bit_cast(v16f, (take_max & __builtin_bit_cast(v16i, amax)) |
                                                (~take_max & __builtin_bit_cast(v16i, oe)));
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
    R = __builtin_bit_cast(v16f, (blend & __builtin_bit_cast(v16i, R2)) | (~blend & __builtin_bit_cast(v16i, R)));
    G = __builtin_bit_cast(v16f, (blend & __builtin_bit_cast(v16i, G2)) | (~blend & __builtin_bit_cast(v16i, G)));
    B = __builtin_bit_cast(v16f, (blend & __builtin_bit_cast(v16i, B2)) | (~blend & __builtin_bit_cast(v16i, B)));
    D = __builtin_bit_cast(v16f, (blend & __builtin_bit_cast(v16i, D2)) | (~blend & __builtin_bit_cast(v16i, D)));
    T = __builtin_bit_cast(v16f, (blend & __builtin_bit_cast(v16i, next_t)) | (~blend & __builtin_bit_cast(v16i, T)));
    const v16i s16 = s1;
    N = (blend & s16) | (~blend & N);
    __builtin_memcpy(pT, &T, 64);
    __builtin_memcpy(pR, &R, 64);
    __builtin_memcpy(pG, &G, 64);
    __builtin_memcpy(pB, &B, 64);
    __builtin_memcpy(pD, &D, 64);
    __builtin_memcpy(pN, &N, 64);
    return n_stop;
#endif
"""

# For tests: how many of the 16 floats with bits lo + (16 b + l) stride (l < 16, the first n) get other
# bits from the lanes' exp than from the C library's expf (what wp.exp calls).
_EXP16_MISMATCHES = r"""
#if defined(__CUDA_ARCH__) || !defined(__AVX2__) || !defined(__FMA__)
    return 0;
#else
""" + _TYPES + r"""
    v16f power;
    v16i run;
    for (int l = 0; l < 16; ++l) {
        const unsigned long long j = (unsigned long long)b * 16ULL + (unsigned long long)l;
        const unsigned long long bits = (unsigned long long)lo + j * (unsigned long long)stride;
        power[l] = __builtin_bit_cast(float, (unsigned int)(bits & 0xffffffffULL));
        run[l] = j < (unsigned long long)n ? -1 : 0;
    }
""" + _EXP16 + r"""
    int bad = 0;
    typedef __typeof__(::expf)* expf_fn;
    expf_fn volatile ref_expf = &::expf;
    for (int l = 0; l < 16; ++l) {
        const float got = e[l];
        const float want = ref_expf(power[l]);
        if (run[l] != 0 && __builtin_bit_cast(unsigned int, got) != __builtin_bit_cast(unsigned int, want))
            ++bad;
    }
    return bad;
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


@wp.func_native(_EXP16_MISMATCHES)
def exp16_mismatches(lo: wp.uint32, stride: wp.uint32, b: int, n: int) -> int: ...


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
