"""The compositing forward and backward on the CPU in C++, eight rays at once in vector lanes (float32).

The same quadrature as `composite._composite_forward_kernel` (its module docstring), with the
factors e_k = exp(-sigma_k delta_k) given (NumPy's pass filled them), or, with `fused`, evaluated
here: a group's samples [o_{r0}, o_{r0+8}) are contiguous, and 16 at a time each gets
e_k = exp(-(sigma_k delta_k)) (the product rounded, then negated, as NumPy's pass computes it) with
NumPy's float32 exp reproduced bit for bit (kernels._npexp), into one slot of a two-slot ring on
the thread's stack (RING samples a slot), from which the steps read them back; with keep = 1 also
into `factor` (every sample, past termination too, as the pass does), by non-temporal 64-byte
stores where aligned, so that the N-sized array streams out without being read for ownership;
with keep = 0 `factor` is neither read nor written. A group of more than RING samples (keep = 1
only: composite.py sends keep = 0 calls with such groups to keep = 1 with a scratch array) has its
factors filled into `factor` alone and read back from there. With the value check, one
unsigned maximum of the bits of sigma and delta flags the group's rays with 2 in out_bad
(composite.py then runs the exact checks). A forward thread takes GROUPS groups one after the
other: the first group's factors are filled before its steps, each later group's 16 a step during
the steps of the group before it (the rest after them), so that this stream of sigma and delta
overlaps the gathers. For each ray the same float32 operations in the same
order, so the same outputs bit for bit. Lane l of a group runs
ray r = r0 + l; at step i every lane still running takes its sample k = o_r + i:

    run  = i < n_r  and  not (T < t_threshold)           (early termination before sample k)
    w = T (1 - e_k);  T' = T e_k;  C' = C + w c_k (each channel);  D' = D + w z_k
    n_used = the number of steps the lane ran

each product and each sum its own statement and floating-point contraction off, so no fused
multiply-add appears (none does in Warp's generated code either). Lanes that have ended keep their
values (a select by the run mask); what they read (their factor replaced by 1) nothing uses. The
step count is the longest ray of the group: the sample indices are o_r + i whatever the lanes'
transmittances, so the loads do not wait on the recurrence. With `fused` (offsets covering the N
samples, non-decreasing) the steps go in blocks of eight: each lane loads samples o_r + i0 ..
o_r + i0 + 7 of every array as one unaligned vector (three for the interleaved colours), element
by element where that would pass the group's last sample, and 8 x 8 register transposes give the
eight steps' lane vectors (5 transposes of 24 shuffles against 40 gathers of 8); without it each
step gathers its sample, clamped to N - 1. The
optional value check adds up, per lane after the loop, the colours and depths of the samples
after early termination exactly as the Warp kernel does, and flags the ray when any sum is NaN or
infinite. Rays past the last of a group of eight get no lanes' results written.

The backward (`composite._composite_backward_kernel`) the same way: per lane, the ray's cotangents,
total = g_C . (C - T_N b) + g_D D and tail = T_N (g_A - g_C . b) in scalar code as the Warp kernel
computes them; then at step i every lane with i < n_used (nothing depends on the transmittance
here) takes its sample k = o_r + i:

    w = T (1 - e_k);  f = ((g_r c_r + g_g c_g) + g_b c_b) + g_D z_k;  prefix' = prefix + w f
    T' = T e_k;  dL/dsigma_k = delta_k ((T' f - (total - prefix')) + tail);  dL/dc_k = g_C w

and stores its two gradients; the samples after n_used get zeros. The steps go in blocks of eight as
in the fused forward (each lane's eight samples of F, z, delta and the colours as row vectors, element
by element clamped to N - 1 where a row would pass N, and 8 x 8 register transposes); the eight steps'
gradient columns are transposed back into rows, stored as vectors where the lane runs all eight
steps, element by element up to n_used otherwise. Both kernels
prefetch the next group's samples (its gradients too, in the backward) over the steps of the
current group: eight rays in lanes read eight streams, which the hardware prefetcher alone served
more slowly than the Warp kernel's one stream (in DRAM, without this, the backward was slower than
the Warp kernel and the forward no faster). The fused forward's factor loop reads sigma and delta
as two contiguous streams, left to the hardware prefetcher (prefetching them too was slower).

Why. The Warp kernel runs one ray per thread: its loop-carried product T e_k and the scalar loads
cost ~3.1-3.3 ns a sample on a core (docs/performance.md, Compositing, fourth round), and Warp has
no way to put several rays in SIMD lanes. `forward_kernel()` and `backward_kernel()` are launched on
the CPU only, for float32 and contiguous sample arrays; float64 and CUDA keep the Warp kernels.
"""

from typing import Any

import warp as wp

from kernels._native import SELECT_CPP, built_once
from kernels._npexp import NPEXP16, NPEXP_TYPES

LANES = 8  # rays in the lanes of a group
GROUPS = 8  # groups of LANES rays per thread of the forward kernel
RING = 2048  # samples a slot of the forward's two-slot factor ring (keep=0): 8 KB of float32, a slot

# One front-to-back step of the quadrature on eight lanes (module docstring), for this module's forward and
# kernels.volume.spheres_cpu's: where `run`, w = T (1 - e), T' = T e, C' = C + w c (each channel), D' = D + w z,
# each product and sum rounded on its own (contraction off); elsewhere T, C and D keep their values. Paste after
# the v8f / v8i typedefs and SELECT_CPP.
BLEND8_CPP = r"""
    auto blend8 = [&](const v8i run, const v8f e, const v8f c0, const v8f c1, const v8f c2, const v8f zk, v8f& T,
                     v8f& R, v8f& G, v8f& B, v8f& D) __attribute__((always_inline)) {
#pragma clang fp contract(off)
        const v8f om = (v8f)1.0f - e;
        const v8f w = T * om;
        const v8f Tn = T * e;
        const v8f wr = w * c0;
        const v8f wg = w * c1;
        const v8f wb = w * c2;
        const v8f wd = w * zk;
        const v8f Rn = R + wr;
        const v8f Gn = G + wg;
        const v8f Bn = B + wb;
        const v8f Dn = D + wd;
        T = sel(run, Tn, T);
        R = sel(run, Rn, R);
        G = sel(run, Gn, G);
        B = sel(run, Bn, B);
        D = sel(run, Dn, D);
    };
"""

_TRANSPOSE8 = r"""
    // out[j * os][l] = in[l * is][j]: an 8 x 8 transpose in registers (unpack, shuffle, 128-bit lane swap)
    auto transpose8 = [](const v8f* in, int is, v8f* out, int os) __attribute__((always_inline)) {
        const v8f t0 = __builtin_shufflevector(in[0], in[is], 0, 8, 1, 9, 4, 12, 5, 13);
        const v8f t1 = __builtin_shufflevector(in[0], in[is], 2, 10, 3, 11, 6, 14, 7, 15);
        const v8f t2 = __builtin_shufflevector(in[2 * is], in[3 * is], 0, 8, 1, 9, 4, 12, 5, 13);
        const v8f t3 = __builtin_shufflevector(in[2 * is], in[3 * is], 2, 10, 3, 11, 6, 14, 7, 15);
        const v8f t4 = __builtin_shufflevector(in[4 * is], in[5 * is], 0, 8, 1, 9, 4, 12, 5, 13);
        const v8f t5 = __builtin_shufflevector(in[4 * is], in[5 * is], 2, 10, 3, 11, 6, 14, 7, 15);
        const v8f t6 = __builtin_shufflevector(in[6 * is], in[7 * is], 0, 8, 1, 9, 4, 12, 5, 13);
        const v8f t7 = __builtin_shufflevector(in[6 * is], in[7 * is], 2, 10, 3, 11, 6, 14, 7, 15);
        const v8f u0 = __builtin_shufflevector(t0, t2, 0, 1, 8, 9, 4, 5, 12, 13);
        const v8f u1 = __builtin_shufflevector(t0, t2, 2, 3, 10, 11, 6, 7, 14, 15);
        const v8f u2 = __builtin_shufflevector(t1, t3, 0, 1, 8, 9, 4, 5, 12, 13);
        const v8f u3 = __builtin_shufflevector(t1, t3, 2, 3, 10, 11, 6, 7, 14, 15);
        const v8f u4 = __builtin_shufflevector(t4, t6, 0, 1, 8, 9, 4, 5, 12, 13);
        const v8f u5 = __builtin_shufflevector(t4, t6, 2, 3, 10, 11, 6, 7, 14, 15);
        const v8f u6 = __builtin_shufflevector(t5, t7, 0, 1, 8, 9, 4, 5, 12, 13);
        const v8f u7 = __builtin_shufflevector(t5, t7, 2, 3, 10, 11, 6, 7, 14, 15);
        out[0 * os] = __builtin_shufflevector(u0, u4, 0, 1, 2, 3, 8, 9, 10, 11);
        out[1 * os] = __builtin_shufflevector(u1, u5, 0, 1, 2, 3, 8, 9, 10, 11);
        out[2 * os] = __builtin_shufflevector(u2, u6, 0, 1, 2, 3, 8, 9, 10, 11);
        out[3 * os] = __builtin_shufflevector(u3, u7, 0, 1, 2, 3, 8, 9, 10, 11);
        out[4 * os] = __builtin_shufflevector(u0, u4, 4, 5, 6, 7, 12, 13, 14, 15);
        out[5 * os] = __builtin_shufflevector(u1, u5, 4, 5, 6, 7, 12, 13, 14, 15);
        out[6 * os] = __builtin_shufflevector(u2, u6, 4, 5, 6, 7, 12, 13, 14, 15);
        out[7 * os] = __builtin_shufflevector(u3, u7, 4, 5, 6, 7, 12, 13, 14, 15);
    };
"""

_FORWARD_CPP = r"""
#if !defined(__CUDA_ARCH__)
  {
#pragma clang fp contract(off)
    typedef float v8f __attribute__((ext_vector_type(8)));
    typedef int v8i __attribute__((ext_vector_type(8)));
""" + NPEXP_TYPES + SELECT_CPP + BLEND8_CPP + r"""
    typedef unsigned int v16u __attribute__((ext_vector_type(16)));
""" + _TRANSPOSE8 + r"""    enum { GROUPS = """ + str(GROUPS) + r""" };  // groups of eight rays a call
    enum { RING = """ + str(RING) + r""" };  // samples a slot of the ring (keep == 0)
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
""" + NPEXP16 + r"""
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
            transpose8(cr, 3, cc, 1);
            transpose8(cr + 1, 3, cc + 8, 1);
            transpose8(cr + 2, 3, cc + 16, 1);
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
"""

_BACKWARD_CPP = r"""
#if !defined(__CUDA_ARCH__)
  {
#pragma clang fp contract(off)
#define DRLAB_AT1(a, T, i) (*(const T*)((const char*)(a).data + (long long)(i) * (a).strides[0]))
#define DRLAB_AT2(a, i, j) (*(const float*)((const char*)(a).data + (long long)(i) * (a).strides[0] + (long long)(j) * (a).strides[1]))
    typedef float v8f __attribute__((ext_vector_type(8)));
    typedef int v8i __attribute__((ext_vector_type(8)));
""" + SELECT_CPP + r"""""" + _TRANSPOSE8 + r"""    const float* F = (const float*)factor.data;
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
        transpose8(cr, 3, cc, 1);
        transpose8(cr + 1, 3, cc + 8, 1);
        transpose8(cr + 2, 3, cc + 16, 1);
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
        transpose8(gcc, 1, gcr, 3);
        transpose8(gcc + 8, 1, gcr + 1, 3);
        transpose8(gcc + 16, 1, gcr + 2, 3);
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
"""


_kernels: dict = {}


def forward_kernel() -> Any:
    """The C++ forward kernel (float32; module docstring), built once."""
    return built_once(_kernels, "forward", _build)


def backward_kernel() -> Any:
    """The C++ backward kernel (float32; module docstring), built once."""
    return built_once(_kernels, "backward", _build_backward)


def _build_backward() -> Any:
    f32 = wp.array(dtype=wp.float32)
    f32_2 = wp.array2d(dtype=wp.float32)
    i32 = wp.array(dtype=wp.int32)

    def composite_grads8_cpu(factor: f32, rgb: f32_2, delta: f32, z: f32, offsets: i32, background: f32_2,
                             per_ray: int, out_rgb: f32_2, out_depth: f32, out_transmittance: f32, out_n_used: i32,
                             grad_rgb: f32_2, grad_depth: f32, grad_opacity: f32, grad_sigma: f32,
                             grad_sample_rgb: f32_2, r0: int): ...

    native = wp.func_native(_BACKWARD_CPP)(composite_grads8_cpu)

    @wp.kernel(module="unique", module_options={"enable_backward": False})
    def composite_backward_cpu(factor: f32, rgb: f32_2, delta: f32, z: f32, offsets: i32, background: f32_2,
                               per_ray: int, out_rgb: f32_2, out_depth: f32, out_transmittance: f32,
                               out_n_used: i32, grad_rgb: f32_2, grad_depth: f32, grad_opacity: f32,
                               grad_sigma: f32, grad_sample_rgb: f32_2, offset: int):
        # thread g = rays 8 g .. 8 g + 7
        g = wp.tid() + offset
        native(factor, rgb, delta, z, offsets, background, per_ray, out_rgb, out_depth, out_transmittance,
               out_n_used, grad_rgb, grad_depth, grad_opacity, grad_sigma, grad_sample_rgb, g * 8)

    return composite_backward_cpu


def _build() -> Any:
    f32 = wp.array(dtype=wp.float32)
    f32_2 = wp.array2d(dtype=wp.float32)
    i32 = wp.array(dtype=wp.int32)

    def composite_rays8_cpu(sigma: f32, delta: f32, fused: int, keep: int, factor: f32, rgb: f32_2, z: f32, offsets: i32, background: f32_2, per_ray: int,
                            t_threshold: wp.float32, out_rgb: f32_2, out_depth: f32, out_opacity: f32,
                            out_transmittance: f32, out_n_used: i32, check_values: int, out_bad: i32,
                            grp: int): ...

    native = wp.func_native(_FORWARD_CPP)(composite_rays8_cpu)

    @wp.kernel(module="unique", module_options={"enable_backward": False})
    def composite_forward_cpu(sigma: f32, delta: f32, fused: int, keep: int, factor: f32, rgb: f32_2, z: f32, offsets: i32, background: f32_2, per_ray: int,
                              t_threshold: wp.float32, out_rgb: f32_2, out_depth: f32, out_opacity: f32,
                              out_transmittance: f32, out_n_used: i32, check_values: int, out_bad: i32,
                              offset: int):
        # thread g = rays 8 GROUPS g .. 8 GROUPS (g + 1) - 1
        g = wp.tid() + offset
        native(sigma, delta, fused, keep, factor, rgb, z, offsets, background, per_ray, t_threshold, out_rgb, out_depth, out_opacity,
               out_transmittance, out_n_used, check_values, out_bad, g)

    return composite_forward_cpu
