// The set-up shared by kernels/volume/spheres_cpu.py's C++ passes (spheres_exponents.cpp,
// spheres_factors.cpp, spheres_composite.cpp, spheres_render.cpp): contraction off, the eight-lane
// types, lanes.h, blend_sums.h and blend8.h, group g = g_lo + tid of eight rays r = 8 g + l (lanes past the last ray
// repeat it), lanes_at(base, s0, s1, j) (column j of an (R, S) float32 array for every lane's ray; one
// load when s0 = 0), and the sphere tables G (K, 4: centre c_k, radius r_k) and P (K, 4: colour, s_k).

#pragma clang fp contract(off)
    typedef float v8f __attribute__((ext_vector_type(8)));
    typedef int v8i __attribute__((ext_vector_type(8)));
#include "lanes.h"
#include "blend_sums.h"
#include "blend8.h"
    const int n_s = t.shape[1];
    const long long ts0 = t.strides[0];
    const long long ts1 = t.strides[1];
    const char* tb = (const char*)t.data;
    const int n_k = geometry.shape[0];
    const int g = g_lo + tid;
    int rl[8];
    for (int l = 0; l < 8; ++l) {
        const int r = 8 * g + l;
        rl[l] = r < n_rays ? r : n_rays - 1;
    }
    // column j of a (R, S) float32 array (base, strides s0, s1) for every lane's ray: one load when its rows are
    // one row (s0 = 0)
    auto lanes_at = [&](const char* base, const long long s0, const long long s1, const int j) -> v8f {
        v8f v;
        if (s0 == 0) {
            v = *(const float*)(base + (long long)j * s1);
        } else {
            for (int l = 0; l < 8; ++l)
                v[l] = *(const float*)(base + (long long)rl[l] * s0 + (long long)j * s1);
        }
        return v;
    };

    const float* G = (const float*)geometry.data;  // (K, 4) contiguous: c_k, r_k
    const float* P = (const float*)appearance.data;  // (K, 4) contiguous: col_k, s_k
