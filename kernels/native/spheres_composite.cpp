// kernels/volume/spheres_cpu.py, spheres_composite8: pass 3 (spheres_pass3.h) for group g_lo + tid, from
// its slices of the falloffs and factors, into the pixels. Does nothing on CUDA and on CPUs without AVX2.

#if defined(__CUDA_ARCH__) || !defined(__AVX2__)
    return;
#else
#include "spheres_common.h"

    const v8f* F = (const v8f*)((const float*)falloff.data + (long long)tid * n_s * n_k * 8);
    const v8f* E = (const v8f*)((const float*)factor.data + (long long)tid * n_s * 8);
#include "spheres_pass3.h"
#endif
