// kernels/splat/rowblend.py, blend_row: one splat blended into one 16-pixel row of a tile, 16 pixels in
// vector lanes, the rasteriser's per-pixel step with its float32 operations in its order:
// power = (-1/2)((qa dx) dx + (qc dy) dy) - (qb dx) dy, alpha = min(alpha_max, o exp(power)) with
// vexp16.h's exp (glibc expf's bits), next_T = T (1 - alpha), stop below t_stop, else w = alpha T and
// rgb, depth += w c; returns how many pixels stopped. Returns 0 (does nothing) on CUDA and on CPUs
// without AVX2 / FMA.

#if defined(__CUDA_ARCH__) || !defined(__AVX2__) || !defined(__FMA__)
    return 0;
#else
#include "vexp_types.h"
#include "lanes.h"
#include "blend_sums.h"

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
#include "vexp16.h"

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
    blend_sums(blend, w, c0, c1, c2, z, R, G, B, D);
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
