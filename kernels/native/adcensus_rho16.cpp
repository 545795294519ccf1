// kernels/stereo/adcensus_kernels.py, _rho16: w rho(c) = w (1 - exp(-c inv)) on 16 float32 lanes, _robust_term's
// operations in its order on each lane, with vexp16.h's exp (glibc expf's bits, wp.exp's on the CPU);
// contraction off. Where vexp16.h is not compiled (CUDA, CPUs without AVX2 / FMA) wp.exp lane by lane.

#if defined(__CUDA_ARCH__) || !defined(__AVX2__) || !defined(__FMA__)
    wp::vec_t<16, float> res;
    for (int l = 0; l < 16; ++l) {
        const float nc = -c.c[l];
        const float p = nc * inv;
        const float e = wp::exp(p);
        const float om = 1.0f - e;
        res.c[l] = weight * om;
    }
    return res;
#else
    {
#pragma clang fp contract(off)
#include "vexp_types.h"

    v16f cv;
    __builtin_memcpy(&cv, &c, 64);
    const v16f nc = -cv;
    const v16f power = nc * inv;
    const v16i run = -1;
#include "vexp16.h"

    const v16f one16 = 1.0f;
    const v16f om = one16 - e;
    const v16f w16 = weight * om;
    wp::vec_t<16, float> res;
    __builtin_memcpy(&res, &w16, 64);
    return res;
    }
#endif
