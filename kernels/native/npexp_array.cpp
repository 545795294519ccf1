// kernels/_npexp.py, npexp16_block(x, y, b): y[k] = NumPy's float32 exp of x[k] (npexp16.h) for the 16
// values k = 16 b .. 16 b + 15 below len(x); the kernel that checks the copy against np.exp and that the
// tests sweep. Empty where __CUDA_ARCH__ is defined.

#if !defined(__CUDA_ARCH__)
  {
#pragma clang fp contract(off)
#include "npexp_types.h"

    const float* X = (const float*)x.data;
    float* Y = (float*)y.data;
    const int n = x.shape[0];
    const int k0 = b * 16;
    v16f nx = 0.0f;
    for (int l = 0; l < 16; ++l)
        if (k0 + l < n)
            nx[l] = X[k0 + l];
#include "npexp16.h"

    for (int l = 0; l < 16; ++l)
        if (k0 + l < n)
            Y[k0 + l] = ne[l];
  }
#endif
