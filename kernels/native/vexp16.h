// e = exp(xin) on 16 float32 lanes, xin = `power` (v16f) in the lanes of the mask `run` (v16i, -1 where
// running; other lanes get x = 0), with the bits of glibc's expf (__expf_fma, glibc 2.27 and later, what
// wp.exp calls on the CPU): in float64 lanes z = x 32 / ln 2, k = round(z) by adding and subtracting
// 1.5 2^52, r = z - k, 2^(k/32) from TAB[k mod 32] plus k's high bits in the exponent field,
// exp(x) ~ (C0 r^3 + C1 r^2 + C2 r + 1) 2^(k/32) with glibc's fused products, one rounding to float32.
// A vector with a running lane outside that fast path (|x| >= 88, inf, NaN) calls expf lane by lane.
// kernels/_vexp.py's docstring states it in full. Needs vexp_types.h before it; only for code compiled
// where the CPU has AVX2 and FMA. Used by rowblend.cpp, adcensus_rho16.cpp and vexp_mismatches.cpp.

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
