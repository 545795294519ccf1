// kernels/volume/spheres_cpu.py, spheres_exponents8: pass 1 (spheres_pass1.h) for group g_lo + tid into
// its slice of out_exponent. Does nothing on CUDA and on CPUs without AVX2.

#if defined(__CUDA_ARCH__) || !defined(__AVX2__)
    return;
#else
#include "spheres_common.h"

    v8f* out1 = (v8f*)((float*)out_exponent.data + (long long)tid * n_s * n_k * 8);
#include "spheres_pass1.h"
#endif
