// kernels/volume/spheres_cpu.py, spheres_render8: the three passes on one group with NumPy's float32 exp
// (npexp16.h, the same bits as np.exp) in place between them, in the chunk's scratch (one group's
// values, reused group after group), the last values of a pass in a padded vector. Does nothing on
// CUDA and on CPUs without AVX2.

#if defined(__CUDA_ARCH__) || !defined(__AVX2__)
    return;
#else
#include "spheres_common.h"
#include "npexp_types.h"

    auto exp_in_place = [](float* p, const long long n) {
        long long i = 0;
        for (; i + 16 <= n; i += 16) {
            v16f nx;
            __builtin_memcpy(&nx, p + i, sizeof(nx));
#include "npexp16.h"

            __builtin_memcpy(p + i, &ne, sizeof(ne));
        }
        if (i < n) {
            float tail[16] = {0.0f};
            __builtin_memcpy(tail, p + i, (n - i) * sizeof(float));
            v16f nx;
            __builtin_memcpy(&nx, tail, sizeof(nx));
#include "npexp16.h"

            __builtin_memcpy(tail, &ne, sizeof(ne));
            __builtin_memcpy(p + i, tail, (n - i) * sizeof(float));
        }
    };
    v8f* out1 = (v8f*)scratch_falloff.data;
    v8f* out2 = (v8f*)scratch_factor.data;
#include "spheres_pass1.h"

    exp_in_place((float*)out1, (long long)n_s * n_k * 8);
    const v8f* F = out1;
#include "spheres_pass2.h"

    exp_in_place((float*)out2, (long long)n_s * 8);
    const v8f* E = out2;
#include "spheres_pass3.h"
#endif
