// kernels/volume/spheres_cpu.py, spheres_factors8: pass 2 (spheres_pass2.h) for group g_lo + tid, from
// its slice of the falloffs into its slice of out_exponent. Does nothing on CUDA and on CPUs without AVX2.

#if defined(__CUDA_ARCH__) || !defined(__AVX2__)
    return;
#else
#include "spheres_common.h"

    const v8f* F = (const v8f*)((const float*)falloff.data + (long long)tid * n_s * n_k * 8);
    v8f* out2 = (v8f*)((float*)out_exponent.data + (long long)tid * n_s * 8);
#include "spheres_pass2.h"
#endif
