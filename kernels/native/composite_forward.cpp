// kernels/volume/composite_cpu.py, composite_rays8_cpu: the compositing forward (the quadrature of
// kernels/volume/composite.py: w = T (1 - e_k), T' = T e_k, C' = C + w c_k, D' = D + w z_k, early
// termination before T < t_threshold) for GROUPS groups of eight rays, a ray a vector lane, float32.
// The factors e_k = exp(-sigma_k delta_k) are given, or (fused) computed here with NumPy's bits
// (npexp16.h) into a two-slot ring of RING samples (and into `factor` with keep); the same float32
// operations in the same order as the Warp kernel, contraction off, so the same bits. The Python
// module's docstring states the layout, the blocks of eight steps and the prefetches. Empty on CUDA.
// Template parameters: GROUPS (groups of eight rays a thread), RING (samples a ring slot).

#if !defined(__CUDA_ARCH__)
  {
#pragma clang fp contract(off)
    typedef float v8f __attribute__((ext_vector_type(8)));
    typedef int v8i __attribute__((ext_vector_type(8)));
#include "npexp_types.h"
#include "lanes.h"
#include "blend_sums.h"
#include "blend8.h"

    typedef unsigned int v16u __attribute__((ext_vector_type(16)));
#include "transpose8.h"
    enum { GROUPS = @GROUPS@ };  // groups of eight rays a call
    enum { RING = @RING@ };  // samples a slot of the ring (keep == 0)
    // keep == 0 (fused only): a group's factors live in one slot of this two-slot ring (the current group's, and
    // the next group's being filled during its steps), never in `factor`; composite.py sends a group of more than
    // RING samples to the keep path with a scratch `factor` instead
    float ring[2][RING] __attribute__((aligned(64)));
    const int r_first = grp * (8 * GROUPS);
    const float* F = (const float*)factor.data;
    const float* S = (const float*)sigma.data;
    const float* Dl = (const float*)delta.data;
    const char* Cb = (const char*)rgb.data;
    const long long cs0 = rgb.strides[0];
    const long long cs1 = rgb.strides[1];
    const float* Zp = (const float*)z.data;
    const int* O = (const int*)offsets.data;
    const int n_rays = offsets.shape[0] - 1;
    const int last = z.shape[0] - 1;  // N - 1 (`factor` has N entries too, but none when the ring holds them)
    float* Fw = (float*)factor.data;
    const int stored = fused == 0 || keep != 0;  // the factors in `factor` (given, or filled here), else in the ring
    // fused: the factors of samples [k, k + m), m <= 16: exp(-(sigma delta)) with NumPy's bits (the product
    // rounded, then negated), into dst[0, m) (`factor` + k, or a ring slot); with the value check, `top` takes the
    // unsigned maximum of the bits of sigma and delta (finite and >= 0 iff at most 0x7f7fffff)
    auto fill16 = [&](int k, int m, v16u& top, float* dst, float* dst2) {
#pragma clang fp contract(off)
        v16f sv = 0.0f;
        v16f dv = 0.0f;
        if (m == 16) {
            __builtin_memcpy(&sv, S + k, sizeof(sv));
            __builtin_memcpy(&dv, Dl + k, sizeof(dv));
        } else {
            for (int l = 0; l < m; ++l) {
                sv[l] = S[k + l];
                dv[l] = Dl[k + l];
            }
        }
        if (check_values != 0) {
            top = __builtin_elementwise_max(top, __builtin_bit_cast(v16u, sv));
            top = __builtin_elementwise_max(top, __builtin_bit_cast(v16u, dv));
        }
        const v16f sd = sv * dv;
        const v16f nx = -sd;
#include "npexp16.h"

        if (m == 16) {
            __builtin_memcpy(dst, &ne, sizeof(ne));
            if (dst2 != nullptr) {
                if (((unsigned long long)dst2 & 63) == 0)
                    __builtin_nontemporal_store(ne, (v16f*)dst2);
                else
                    __builtin_memcpy(dst2, &ne, sizeof(ne));
            }
        } else {
            for (int l = 0; l < m; ++l)
                dst[l] = ne[l];
            if (dst2 != nullptr)
                for (int l = 0; l < m; ++l)
                    dst2[l] = ne[l];
        }
    };
    // where sample k of a group whose samples start at `base` gets its factor, in ring slot `slot` when keep == 0
    // (a group never holds more than RING samples there: composite.py checks; the guard only keeps the writes
    // inside the slot)
    auto fill_at = [&](int k, int m, v16u& top, int base, int slot, int gsz) {
        if (stored != 0 && gsz <= RING)
            fill16(k, m, top, ring[slot] + (k - base), Fw + k);
        else if (stored != 0)
            fill16(k, m, top, Fw + k, nullptr);
        else if (k - base + m <= RING)
            fill16(k, m, top, ring[slot] + (k - base), nullptr);
    };
    // the first group's factors before its steps; each later group's during the steps of the one before
    v16u top_cur = 0u;
    if (fused != 0 && r_first < n_rays) {
        const int ga = O[r_first];
        const int gb = O[r_first + 8 < n_rays ? r_first + 8 : n_rays];
        for (int k = ga; k < gb; k += 16)
            fill_at(k, gb - k < 16 ? gb - k : 16, top_cur, ga, 0, gb - ga);
    }
    for (int gq = 0; gq < GROUPS; ++gq) {
    const int r0 = r_first + 8 * gq;
    if (r0 >= n_rays)
        break;
    const int sd_bad = __builtin_reduce_max(top_cur) > 0x7f7fffffu ? 2 : 0;
    int nk = 0;
    int nb = 0;
    int nbase = 0;
    const int slot = gq & 1;
    v16u top_next = 0u;
    if (fused != 0 && gq + 1 < GROUPS && r0 + 8 < n_rays) {
        nk = O[r0 + 8];
        nb = O[r0 + 16 < n_rays ? r0 + 16 : n_rays];
        nbase = nk;
    }
    v8i start, len;
    int maxlen = 0;
    for (int l = 0; l < 8; ++l) {
        const int r = r0 + l;
        start[l] = 0;
        len[l] = 0;
        if (r < n_rays) {
            start[l] = O[r];
            len[l] = O[r + 1] - O[r];
        }
        maxlen = len[l] > maxlen ? len[l] : maxlen;
    }
    // the gathers' factors: `factor` by sample index, or (keep == 0) this group's slot by index - ga, clamped into
    // the group's [0, gn) (lanes that ended or have no ray read an entry they then replace by 1)
    const int ga = O[r0];
    const int gn = O[r0 + 8 < n_rays ? r0 + 8 : n_rays] - ga;
    const float* Fg = stored != 0 ? F : ring[slot];
    const v8f thr = t_threshold;
    const v8f one = 1.0f;
    v8f T = one;
    v8f R = 0.0f;
    v8f G = 0.0f;
    v8f B = 0.0f;
    v8f D = 0.0f;
    v8i used = 0;
    // the next group's samples [pa, pb), prefetched 16 a step (a hint: bits do not depend on it)
    const int pa = r0 + 8 < n_rays ? O[r0 + 8] : 0;
    const int pb = r0 + 8 < n_rays ? O[(r0 + 16 < n_rays ? r0 + 16 : n_rays)] : 0;
    // one step: the prefetch of the next group, the run mask, the recurrence on the lanes' sample values e (the
    // factor), c0, c1, c2 (colour) and zk (depth), the next group's 16 factors; false when no lane runs (the
    // group's loop ends)
    auto step = [&](int i, v8f e, v8f c0, v8f c1, v8f c2, v8f zk) __attribute__((always_inline)) -> bool {
#pragma clang fp contract(off)
        const int p = pa + 16 * i;
        if (p < pb) {
            // fused: the factor loop streams sigma and delta (the hardware prefetcher serves that; prefetching
            // them here too was 7-10% slower)
            if (fused == 0)
                __builtin_prefetch(F + p);
            __builtin_prefetch(Zp + p);
            const char* pc = Cb + (long long)p * cs0;
            __builtin_prefetch(pc);
            __builtin_prefetch(pc + 64);
            __builtin_prefetch(pc + 128);
        }
        const v8i inside = (v8i)i < len;
        const v8i run = inside & ~(T < thr);
        if (!__builtin_reduce_or(run))
            return false;
        e = sel(run, e, one);
        blend8(run, e, c0, c1, c2, zk, T, R, G, B, D);
        used = used - run;
        if (nk < nb) {  // 16 of the next group's factors
            const int m = nb - nk < 16 ? nb - nk : 16;
            fill_at(nk, m, top_next, nbase, slot ^ 1, nb - nbase);
            nk += m;
        }
        return true;
    };
    if (fused != 0) {
        // blocks of eight steps: each lane loads eight consecutive samples of its ray as one vector per array
        // (three for the interleaved colours), and 8 x 8 register transposes turn the lanes' rows into the
        // eight steps' columns. The group's samples are [ga, gb) (fused: offsets cover N, non-decreasing); a
        // row that would pass gb is loaded element by element up to gb and zero after it: every sample a
        // running lane takes lies before its ray's end <= gb, the rest only feed lanes that do not run (their
        // factor replaced by 1, their values kept by the selects), so the bits are those of the gathers
        const int gb = ga + gn;
        const bool ringed = stored == 0 || gn <= RING;  // the group's factors in its ring slot (keep: also in factor)
        const float* Fb = ringed ? ring[slot] : F;
        const int fb = ringed ? ga : 0;  // sample k's factor is Fb[k - fb]
        const float* Cf = (const float*)Cb;
        v8i lb;  // the lanes' first samples; gb for lanes without a ray (nothing loaded)
        for (int l = 0; l < 8; ++l)
            lb[l] = r0 + l < n_rays ? start[l] : gb;
        bool go = true;
        for (int i0 = 0; go && i0 < maxlen; i0 += 8) {
            v8f fr[8], zr[8], cr[24];
#pragma clang loop unroll(full)
            for (int l = 0; l < 8; ++l) {
                const int k = lb[l] + i0;
                const int m = gb - k;
                if (m >= 8) {
                    __builtin_memcpy(&fr[l], Fb + (k - fb), sizeof(v8f));
                    __builtin_memcpy(&zr[l], Zp + k, sizeof(v8f));
                    __builtin_memcpy(&cr[3 * l], Cf + 3LL * k, 3 * sizeof(v8f));
                } else {
                    fr[l] = 0.0f;
                    zr[l] = 0.0f;
                    cr[3 * l] = 0.0f;
                    cr[3 * l + 1] = 0.0f;
                    cr[3 * l + 2] = 0.0f;
                    for (int j = 0; j < m; ++j) {
                        fr[l][j] = Fb[k - fb + j];
                        zr[l][j] = Zp[k + j];
                        for (int c = 0; c < 3; ++c) {
                            const int q = 3 * j + c;
                            cr[3 * l + q / 8][q % 8] = Cf[3LL * k + q];
                        }
                    }
                }
            }
            // columns: fc[j][l] = lane l's factor at step i0 + j; likewise zc; cc[q][l] = lane l's float q of
            // its 24 colour floats (sample j's channel c at q = 3 j + c)
            v8f fc[8] __attribute__((aligned(64)));
            v8f zc[8] __attribute__((aligned(64)));
            v8f cc[24] __attribute__((aligned(64)));
            transpose8(fr, 1, fc, 1);
            transpose8(zr, 1, zc, 1);
            transpose8_rgb(cr, cc);
            // the steps read the columns back from the stack (one copy of `step` in the loop: unrolling it eight
            // times, with the factor fill inlined into each, was not faster)
            const int jn = maxlen - i0 < 8 ? maxlen - i0 : 8;
#pragma clang loop unroll(disable)
            for (int j = 0; j < jn; ++j) {
                if (!step(i0 + j, fc[j], cc[3 * j], cc[3 * j + 1], cc[3 * j + 2], zc[j])) {
                    go = false;
                    break;
                }
            }
        }
    } else {
    for (int i = 0; i < maxlen; ++i) {
        v8i idx = start + i;
        idx = __builtin_elementwise_min(idx, (v8i)last);
        v8f e, c0, c1, c2, zk;
#if defined(__AVX2__)
        {
            typedef float g8f __attribute__((__vector_size__(32)));
            typedef int g8i __attribute__((__vector_size__(32)));
            const g8f all = (g8f)(v8i)(-1);
            const g8f none = (g8f)(v8f)0.0f;
            const v8i i3 = idx * 3;
            const float* Cf = (const float*)Cb;
            e = (v8f)__builtin_ia32_gatherd_ps256(none, F, (g8i)idx, all, 4);
            zk = (v8f)__builtin_ia32_gatherd_ps256(none, Zp, (g8i)idx, all, 4);
            c0 = (v8f)__builtin_ia32_gatherd_ps256(none, Cf, (g8i)i3, all, 4);
            c1 = (v8f)__builtin_ia32_gatherd_ps256(none, Cf + 1, (g8i)i3, all, 4);
            c2 = (v8f)__builtin_ia32_gatherd_ps256(none, Cf + 2, (g8i)i3, all, 4);
        }
#else
        for (int l = 0; l < 8; ++l) {
            const int k = idx[l];
            const float* c = (const float*)(Cb + (long long)k * cs0);
            e[l] = F[k];
            c0[l] = c[0];
            c1[l] = *(const float*)((const char*)c + cs1);
            c2[l] = *(const float*)((const char*)c + 2 * cs1);
            zk[l] = Zp[k];
        }
#endif
        if (!step(i, e, c0, c1, c2, zk))
            break;
    }
    }
    while (nk < nb) {  // the rest of them
        const int m = nb - nk < 16 ? nb - nk : 16;
        fill_at(nk, m, top_next, nbase, slot ^ 1, nb - nbase);
        nk += m;
    }
    const char* bgb = (const char*)background.data;
    char* ob = (char*)out_rgb.data;
    for (int l = 0; l < 8; ++l) {
        const int r = r0 + l;
        if (r >= n_rays)
            break;
        const float Tl = T[l];
        if (check_values != 0) {
            float rest = 0.0f;
            for (int j = start[l] + used[l]; j < start[l] + len[l]; ++j) {
                const float* c = (const float*)(Cb + (long long)j * cs0);
                const float a0 = c[0];
                const float a1 = *(const float*)((const char*)c + cs1);
                const float a2 = *(const float*)((const char*)c + 2 * cs1);
                const float s1 = a0 + a1;
                const float s2 = s1 + a2;
                const float s3 = s2 + Zp[j];
                rest = rest + s3;
            }
            const bool ok = __builtin_isfinite(R[l]) && __builtin_isfinite(G[l]) && __builtin_isfinite(B[l])
                            && __builtin_isfinite(D[l]) && __builtin_isfinite(rest);
            ((int*)out_bad.data)[r] = (ok ? 0 : 1) | sd_bad;
        }
        const float* bg = (const float*)(bgb + (long long)(r * per_ray) * background.strides[0]);
        const long long bs1 = background.strides[1];
        const float b0 = bg[0];
        const float b1 = *(const float*)((const char*)bg + bs1);
        const float b2 = *(const float*)((const char*)bg + 2 * bs1);
        const float tb0 = Tl * b0;
        const float tb1 = Tl * b1;
        const float tb2 = Tl * b2;
        float* o = (float*)(ob + (long long)r * out_rgb.strides[0]);
        const long long os1 = out_rgb.strides[1];
        o[0] = R[l] + tb0;
        *(float*)((char*)o + os1) = G[l] + tb1;
        *(float*)((char*)o + 2 * os1) = B[l] + tb2;
        ((float*)out_depth.data)[r] = D[l];
        ((float*)out_opacity.data)[r] = 1.0f - Tl;
        ((float*)out_transmittance.data)[r] = Tl;
        ((int*)out_n_used.data)[r] = used[l];
    }
    top_cur = top_next;
    }
    __builtin_ia32_sfence();  // the factors' non-temporal stores
  }
#endif
