"""A float32 exp on 16 SIMD lanes with the bits of glibc's expf (what wp.exp calls on the CPU): C++ snippet text for
wp.func_native kernels (clang vector extensions), shared by kernels.splat.rowblend and kernels.stereo.adcensus.

EXP16 computes e = exp(xin) in the lanes of the mask `run` (v16i, -1 where running) from `power` (v16f), as glibc's
expf (2.27 and later, the variant for CPUs with FMA, __expf_fma) in float64 lanes: z = x N / ln 2 (N = 32),
k = round(z) by adding and subtracting SHIFT = 1.5 * 2^52, r = z - k, 2^(k/N) from the table T[k mod N] = 2^(j/N)
plus k's high bits in the exponent field, exp(x) ~ (C0 r^3 + C1 r^2 + C2 r + 1) 2^(k/N), with glibc's fused products
fma(N / ln 2, x, SHIFT), fma(N / ln 2, x, -k), fma(fma(C0, r, C1), r^2, fma(C2, r, 1)), then one rounding to
float32: the bits of expf for every float32 (all 2^32 inputs were checked once with exp16_mismatches; tests sweep a
sample). Lanes outside that fast path (|x| >= 88, infinite or NaN) make the whole vector call expf itself, lane by
lane; lanes not running get x = 0. TYPES declares the vector types (v16f, v16i, v8f, v8d, v8l) and the table TAB;
a snippet pastes TYPES, sets `power` and `run`, then pastes EXP16. Only for code compiled where the CPU has AVX2
and FMA (guard with `#if defined(__CUDA_ARCH__) || !defined(__AVX2__) || !defined(__FMA__)`: there glibc runs
__expf_fma). A C library whose expf is another algorithm (glibc before 2.27, musl) would make the bits differ from
wp.exp's: exp16_mismatches says so.
"""

from __future__ import annotations

import warp as wp

# Vector types and glibc's table 2^(j/32) (__exp2f_data.tab: bits of 2^(j/32) less j << 47).
TYPES = r"""
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
EXP16 = r"""
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


# For tests: how many of the 16 floats with bits lo + (16 b + l) stride (l < 16, the first n) get other
# bits from the lanes' exp than from the C library's expf (what wp.exp calls).
_MISMATCHES = r"""
#if defined(__CUDA_ARCH__) || !defined(__AVX2__) || !defined(__FMA__)
    return 0;
#else
""" + TYPES + r"""
    v16f power;
    v16i run;
    for (int l = 0; l < 16; ++l) {
        const unsigned long long j = (unsigned long long)b * 16ULL + (unsigned long long)l;
        const unsigned long long bits = (unsigned long long)lo + j * (unsigned long long)stride;
        power[l] = __builtin_bit_cast(float, (unsigned int)(bits & 0xffffffffULL));
        run[l] = j < (unsigned long long)n ? -1 : 0;
    }
""" + EXP16 + r"""
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


@wp.func_native(_MISMATCHES)
def exp16_mismatches(lo: wp.uint32, stride: wp.uint32, b: int, n: int) -> int: ...

