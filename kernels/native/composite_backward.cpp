// kernels/volume/composite_cpu.py, composite_grads8_cpu: the compositing backward
// (composite_kernels._composite_backward_kernel's hand-written adjoint) for the eight rays r0 .. r0 + 7, a ray a
// vector lane, float32: per step w = T (1 - e_k), f = ((g_r c_r + g_g c_g) + g_b c_b) + g_D z_k,
// prefix' = prefix + w f, T' = T e_k, dL/dsigma_k = delta_k ((T' f - (total - prefix')) + tail),
// dL/dc_k = g_C w; the Warp kernel's float32 operations in its order, contraction off, so the same
// bits. Blocks of eight steps through 8 x 8 register transposes (transpose8.h). Empty on CUDA.

#if !defined(__CUDA_ARCH__)
  {
#pragma clang fp contract(off)
#define DRLAB_AT1(a, T, i) (*(const T*)((const char*)(a).data + (long long)(i) * (a).strides[0]))
#define DRLAB_AT2(a, i, j) (*(const float*)((const char*)(a).data + (long long)(i) * (a).strides[0] + (long long)(j) * (a).strides[1]))
    typedef float v8f __attribute__((ext_vector_type(8)));
    typedef int v8i __attribute__((ext_vector_type(8)));
#include "lanes.h"
#include "transpose8.h"
    const float* F = (const float*)factor.data;
    const float* C = (const float*)rgb.data;
    const float* Dl = (const float*)delta.data;
    const float* Zp = (const float*)z.data;
    const int* O = (const int*)offsets.data;
    float* GS = (float*)grad_sigma.data;
    float* GC = (float*)grad_sample_rgb.data;
    const int n_rays = offsets.shape[0] - 1;
    const int last = factor.shape[0] - 1;
    v8i start, used, len;
    v8f GR, GG, GB, GD, total, tail;
    int maxused = 0;
    for (int l = 0; l < 8; ++l) {
        const int r = r0 + l;
        start[l] = 0;
        used[l] = 0;
        len[l] = 0;
        GR[l] = 0.0f;
        GG[l] = 0.0f;
        GB[l] = 0.0f;
        GD[l] = 0.0f;
        total[l] = 0.0f;
        tail[l] = 0.0f;
        if (r < n_rays) {
            // the Warp kernel's per-ray values, operation for operation
            const float gr = DRLAB_AT2(grad_rgb, r, 0);
            const float gg = DRLAB_AT2(grad_rgb, r, 1);
            const float gb = DRLAB_AT2(grad_rgb, r, 2);
            const float gd = DRLAB_AT1(grad_depth, float, r);
            const float tf = DRLAB_AT1(out_transmittance, float, r);
            const int b = r * per_ray;
            const float b0 = DRLAB_AT2(background, b, 0);
            const float b1 = DRLAB_AT2(background, b, 1);
            const float b2 = DRLAB_AT2(background, b, 2);
            const float gb0 = gr * b0;
            const float gb1 = gg * b1;
            const float gb2 = gb * b2;
            const float gbs = gb0 + gb1;
            const float g_bg = gbs + gb2;
            const float x0 = tf * b0;
            const float y0 = DRLAB_AT2(out_rgb, r, 0) - x0;
            const float t0 = gr * y0;
            const float x1 = tf * b1;
            const float y1 = DRLAB_AT2(out_rgb, r, 1) - x1;
            const float t1 = gg * y1;
            const float x2 = tf * b2;
            const float y2 = DRLAB_AT2(out_rgb, r, 2) - x2;
            const float t2 = gb * y2;
            const float td = gd * DRLAB_AT1(out_depth, float, r);
            const float s01 = t0 + t1;
            const float s012 = s01 + t2;
            total[l] = s012 + td;
            const float go = DRLAB_AT1(grad_opacity, float, r) - g_bg;
            tail[l] = tf * go;
            GR[l] = gr;
            GG[l] = gg;
            GB[l] = gb;
            GD[l] = gd;
            start[l] = O[r];
            len[l] = O[r + 1] - O[r];
            used[l] = DRLAB_AT1(out_n_used, int, r);
        }
        maxused = used[l] > maxused ? used[l] : maxused;
    }
    const v8f one = 1.0f;
    v8f T = one;
    v8f prefix = 0.0f;
    const int pa = r0 + 8 < n_rays ? O[r0 + 8] : 0;
    const int pb = r0 + 8 < n_rays ? O[(r0 + 16 < n_rays ? r0 + 16 : n_rays)] : 0;
    // one step on the lanes' sample values e, c0, c1, c2, zk, dk (the prefetch of the next group, the recurrence);
    // the step's gradients into gs (dL/dsigma) and wr, wg, wb (dL/dc)
    auto step = [&](int i, v8f e, v8f c0, v8f c1, v8f c2, v8f zk, v8f dk, v8f& gs, v8f& wr, v8f& wg, v8f& wb)
        __attribute__((always_inline)) {
#pragma clang fp contract(off)
        const int p = pa + 16 * i;
        if (p < pb) {
            __builtin_prefetch(F + p);
            __builtin_prefetch(Zp + p);
            __builtin_prefetch(Dl + p);
            const float* pc = C + 3LL * p;
            __builtin_prefetch(pc);
            __builtin_prefetch(pc + 16);
            __builtin_prefetch(pc + 32);
            __builtin_prefetch(GS + p, 1);
            float* pg = GC + 3LL * p;
            __builtin_prefetch(pg, 1);
            __builtin_prefetch(pg + 16, 1);
            __builtin_prefetch(pg + 32, 1);
        }
        const v8i run = (v8i)i < used;
        e = sel(run, e, one);
        const v8f om = one - e;
        const v8f w = T * om;
        const v8f f0 = GR * c0;
        const v8f f1 = GG * c1;
        const v8f f01 = f0 + f1;
        const v8f f2 = GB * c2;
        const v8f f012 = f01 + f2;
        const v8f fd = GD * zk;
        const v8f f = f012 + fd;
        const v8f wf = w * f;
        const v8f pn = prefix + wf;
        const v8f Tn = T * e;
        const v8f tfv = Tn * f;
        const v8f rest = total - pn;
        const v8f u = tfv - rest;
        const v8f v = u + tail;
        gs = dk * v;
        wr = GR * w;
        wg = GG * w;
        wb = GB * w;
        T = sel(run, Tn, T);
        prefix = sel(run, pn, prefix);
    };
    // blocks of eight steps: a lane loads samples k .. k + 7 (k = o_r + i0) of each array as one vector (three for
    // the colours; element by element, clamped to N - 1 as the gathers were, where k + 8 > N), 8 x 8 register
    // transposes give the steps' lane vectors, and the steps' gradient columns are transposed back into rows, stored
    // as vectors where the lane runs all eight steps, element by element up to n_used otherwise
    const int n = last + 1;
    for (int i0 = 0; i0 < maxused; i0 += 8) {
        v8f fr[8], zr[8], dr[8], cr[24];
#pragma clang loop unroll(full)
        for (int l = 0; l < 8; ++l) {
            const int k = start[l] + i0;
            if (k + 8 <= n) {
                __builtin_memcpy(&fr[l], F + k, sizeof(v8f));
                __builtin_memcpy(&zr[l], Zp + k, sizeof(v8f));
                __builtin_memcpy(&dr[l], Dl + k, sizeof(v8f));
                __builtin_memcpy(&cr[3 * l], C + 3LL * k, 3 * sizeof(v8f));
            } else {
                for (int j = 0; j < 8; ++j) {
                    const long long kk = k + j < last ? k + j : last;
                    fr[l][j] = F[kk];
                    zr[l][j] = Zp[kk];
                    dr[l][j] = Dl[kk];
                    for (int c = 0; c < 3; ++c) {
                        const int q = 3 * j + c;
                        cr[3 * l + q / 8][q % 8] = C[3 * kk + c];
                    }
                }
            }
        }
        v8f fc[8] __attribute__((aligned(64)));
        v8f zc[8] __attribute__((aligned(64)));
        v8f dc[8] __attribute__((aligned(64)));
        v8f cc[24] __attribute__((aligned(64)));
        transpose8(fr, 1, fc, 1);
        transpose8(zr, 1, zc, 1);
        transpose8(dr, 1, dc, 1);
        transpose8_rgb(cr, cc);
        v8f gsc[8] __attribute__((aligned(64)));
        v8f gcc[24] __attribute__((aligned(64)));
        const int jn = maxused - i0 < 8 ? maxused - i0 : 8;
#pragma clang loop unroll(disable)
        for (int j = 0; j < jn; ++j)
            step(i0 + j, fc[j], cc[3 * j], cc[3 * j + 1], cc[3 * j + 2], zc[j], dc[j], gsc[j], gcc[3 * j],
                 gcc[3 * j + 1], gcc[3 * j + 2]);
        for (int j = jn; j < 8; ++j) {  // columns no lane stores
            gsc[j] = 0.0f;
            gcc[3 * j] = 0.0f;
            gcc[3 * j + 1] = 0.0f;
            gcc[3 * j + 2] = 0.0f;
        }
        v8f gsr[8], gcr[24];
        transpose8(gsc, 1, gsr, 1);
        untranspose8_rgb(gcc, gcr);
#pragma clang loop unroll(full)
        for (int l = 0; l < 8; ++l) {
            const int k = start[l] + i0;
            const int m = used[l] - i0;  // the steps this lane runs in the block
            if (m >= 8 && k + 8 <= n) {
                __builtin_memcpy(GS + k, &gsr[l], sizeof(v8f));
                __builtin_memcpy(GC + 3LL * k, &gcr[3 * l], 3 * sizeof(v8f));
            } else {
                for (int j = 0; j < m && j < 8; ++j) {
                    const long long kk = k + j < last ? k + j : last;
                    GS[kk] = gsr[l][j];
                    GC[3 * kk] = gcr[3 * l + (3 * j) / 8][(3 * j) % 8];
                    GC[3 * kk + 1] = gcr[3 * l + (3 * j + 1) / 8][(3 * j + 1) % 8];
                    GC[3 * kk + 2] = gcr[3 * l + (3 * j + 2) / 8][(3 * j + 2) % 8];
                }
            }
        }
    }
    for (int l = 0; l < 8; ++l) {
        for (int j = start[l] + used[l]; j < start[l] + len[l]; ++j) {
            GS[j] = 0.0f;
            GC[3LL * j] = 0.0f;
            GC[3LL * j + 1] = 0.0f;
            GC[3LL * j + 2] = 0.0f;
        }
    }
#undef DRLAB_AT1
#undef DRLAB_AT2
  }
#endif
