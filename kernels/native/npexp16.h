// ne = exp(nx) on 16 float32 lanes (v16f) with the bits of NumPy's float32 exp (its AVX2 / AVX-512
// loop), for kernels/_npexp.py (npexp_array.cpp), kernels/volume/composite_cpu.py (composite_forward.cpp)
// and kernels/volume/spheres_cpu.py (spheres_render.cpp). NaN -> NaN, x >= 88.72283935546875 -> inf,
// x <= -103.97208404541015625 -> 0; else q = rint(x log2 e) (by adding and subtracting 1.5 2^23),
// y = x - q ln 2 in two Cody-Waite fused steps, exp(y) ~ P(y) / Q(y) (a 5/2 rational minimax fit, Horner
// with fused multiply-adds), times 2^q with one rounding (two exact power-of-two products). The constants
// are NumPy's; kernels/_npexp.py's docstring states it in full. Needs npexp_types.h before it and
// floating-point contraction off (`#pragma clang fp contract(off)`).

    v16f ne;
    {
        const v16i nb = __builtin_bit_cast(v16i, nx);
        const v16i is_nan = (nb & 0x7fffffff) > 0x7f800000;
        v16f x = __builtin_bit_cast(v16f, nb & ~is_nan);
        const v16i big = x >= 0x1.62e43p+6f;            // 88.72283935546875
        const v16i small = x <= -0x1.9fe36ap+6f;        // -103.97208404541015625
        x = __builtin_bit_cast(v16f, __builtin_bit_cast(v16i, x) & ~(big | small));
        v16f q = x * 0x1.715476p+0f;                    // LOG2E
        q = q + 0x1.8p+23f;
        q = q - 0x1.8p+23f;
        v16f y = __builtin_elementwise_fma(q, (v16f)-0x1.62e4p-1f, x);
        y = __builtin_elementwise_fma(q, (v16f)-0x1.7f7d1cp-20f, y);
        v16f pn = __builtin_elementwise_fma((v16f)0x1.0a7bbp-11f, y, (v16f)0x1.bae2b2p-8f);
        pn = __builtin_elementwise_fma(pn, y, (v16f)0x1.a2fb18p-5f);
        pn = __builtin_elementwise_fma(pn, y, (v16f)0x1.fa98b0p-3f);
        pn = __builtin_elementwise_fma(pn, y, (v16f)0x1.7397aap-1f);
        pn = __builtin_elementwise_fma(pn, y, (v16f)1.0f);
        v16f pd = __builtin_elementwise_fma((v16f)0x1.61d064p-6f, y, (v16f)-0x1.18d0aep-2f);
        pd = __builtin_elementwise_fma(pd, y, (v16f)1.0f);
        const v16f p = pn / pd;
        // p 2^q with one rounding: q in [-150, 128], h = floor(q / 2), both factors normal powers of two
        const v16i qi = __builtin_convertvector(q, v16i);
        const v16i h = qi >> 1;
        const v16f s1 = __builtin_bit_cast(v16f, (h + 127) << 23);
        const v16f s2 = __builtin_bit_cast(v16f, (qi - h + 127) << 23);
        const v16f ps = p * s1;
        v16i r = __builtin_bit_cast(v16i, ps * s2);
        r = (r & ~is_nan) | (is_nan & 0x7fc00000);
        r = (r & ~big) | (big & 0x7f800000);
        r = r & ~small;
        ne = __builtin_bit_cast(v16f, r);
    }
