"""The compositing forward on the CPU in C++, eight rays at once in vector lanes (float32).

The same quadrature as `composite._composite_forward_kernel` (its module docstring), with the
factors e_k = exp(-sigma_k delta_k) given (the CPU always fills them first), and for each ray the
same float32 operations in the same order, so the same outputs bit for bit. Lane l of a group runs
ray r = r0 + l; at step i every lane still running takes its sample k = o_r + i:

    run  = i < n_r  and  not (T < t_threshold)           (early termination before sample k)
    w = T (1 - e_k);  T' = T e_k;  C' = C + w c_k (each channel);  D' = D + w z_k
    n_used = the number of steps the lane ran

each product and each sum its own statement and floating-point contraction off, so no fused
multiply-add appears (none does in Warp's generated code either). Lanes that have ended keep their
values (a select by the run mask); they read a clamped in-range sample (their factor replaced by
1), which nothing uses. The step count is the longest ray of the group: the sample indices are
o_r + i whatever the lanes' transmittances, so the loads do not wait on the recurrence. The
optional value check adds up, per lane after the loop, the colours and depths of the samples
after early termination exactly as the Warp kernel does, and flags the ray when any sum is NaN or
infinite. Rays past the last of a group of eight get no lanes' results written.

Why. The Warp kernel runs one ray per thread: its loop-carried product T e_k and the scalar loads
cost ~3.1-3.3 ns a sample on a core (docs/performance.md, Compositing, fourth round), and Warp has
no way to put several rays in SIMD lanes. `forward_kernel()` is launched on the CPU only, for
float32; float64 and CUDA keep the Warp kernel.
"""

import threading
from typing import Any

import warp as wp

_FORWARD_CPP = r"""
#if !defined(__CUDA_ARCH__)
  {
#pragma clang fp contract(off)
    typedef float v8f __attribute__((ext_vector_type(8)));
    typedef int v8i __attribute__((ext_vector_type(8)));
    const float* F = (const float*)factor.data;
    const char* Cb = (const char*)rgb.data;
    const long long cs0 = rgb.strides[0];
    const long long cs1 = rgb.strides[1];
    const float* Zp = (const float*)z.data;
    const int* O = (const int*)offsets.data;
    const int n_rays = offsets.shape[0] - 1;
    const int last = factor.shape[0] - 1;
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
    for (int i = 0; i < maxlen; ++i) {
        const int p = pa + 16 * i;
        if (p < pb) {
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
            break;
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
        e = __builtin_bit_cast(v8f, (run & __builtin_bit_cast(v8i, e)) | (~run & __builtin_bit_cast(v8i, one)));
        const v8f om = one - e;
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
        T = __builtin_bit_cast(v8f, (run & __builtin_bit_cast(v8i, Tn)) | (~run & __builtin_bit_cast(v8i, T)));
        R = __builtin_bit_cast(v8f, (run & __builtin_bit_cast(v8i, Rn)) | (~run & __builtin_bit_cast(v8i, R)));
        G = __builtin_bit_cast(v8f, (run & __builtin_bit_cast(v8i, Gn)) | (~run & __builtin_bit_cast(v8i, G)));
        B = __builtin_bit_cast(v8f, (run & __builtin_bit_cast(v8i, Bn)) | (~run & __builtin_bit_cast(v8i, B)));
        D = __builtin_bit_cast(v8f, (run & __builtin_bit_cast(v8i, Dn)) | (~run & __builtin_bit_cast(v8i, D)));
        used = used - run;
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
            ((int*)out_bad.data)[r] = ok ? 0 : 1;
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
  }
#endif
"""

LANES = 8  # rays per thread of the kernel

_lock = threading.Lock()
_kernels: dict = {}


def forward_kernel() -> Any:
    """The C++ forward kernel (float32; module docstring), built once."""
    with _lock:
        k = _kernels.get("forward")
        if k is None:
            k = _kernels["forward"] = _build()
    return k


def _build() -> Any:
    f32 = wp.array(dtype=wp.float32)
    f32_2 = wp.array2d(dtype=wp.float32)
    i32 = wp.array(dtype=wp.int32)

    def composite_rays8_cpu(factor: f32, rgb: f32_2, z: f32, offsets: i32, background: f32_2, per_ray: int,
                            t_threshold: wp.float32, out_rgb: f32_2, out_depth: f32, out_opacity: f32,
                            out_transmittance: f32, out_n_used: i32, check_values: int, out_bad: i32,
                            r0: int): ...

    native = wp.func_native(_FORWARD_CPP)(composite_rays8_cpu)

    @wp.kernel(module="unique", module_options={"enable_backward": False})
    def composite_forward_cpu(factor: f32, rgb: f32_2, z: f32, offsets: i32, background: f32_2, per_ray: int,
                              t_threshold: wp.float32, out_rgb: f32_2, out_depth: f32, out_opacity: f32,
                              out_transmittance: f32, out_n_used: i32, check_values: int, out_bad: i32,
                              offset: int):
        # thread g = rays 8 g .. 8 g + 7
        g = wp.tid() + offset
        native(factor, rgb, z, offsets, background, per_ray, t_threshold, out_rgb, out_depth, out_opacity,
               out_transmittance, out_n_used, check_values, out_bad, g * 8)

    return composite_forward_cpu
