// kernels/_vexp.py, exp16_mismatches(lo, stride, b, n): how many of the 16 floats with bits
// lo + (16 b + l) stride (l < 16, j = 16 b + l < n) get other bits from vexp16.h than from the C
// library's expf (what wp.exp calls); 0 on CUDA and on CPUs without AVX2 / FMA.

#if defined(__CUDA_ARCH__) || !defined(__AVX2__) || !defined(__FMA__)
    return 0;
#else
#include "vexp_types.h"

    v16f power;
    v16i run;
    for (int l = 0; l < 16; ++l) {
        const unsigned long long j = (unsigned long long)b * 16ULL + (unsigned long long)l;
        const unsigned long long bits = (unsigned long long)lo + j * (unsigned long long)stride;
        power[l] = __builtin_bit_cast(float, (unsigned int)(bits & 0xffffffffULL));
        run[l] = j < (unsigned long long)n ? -1 : 0;
    }
#include "vexp16.h"

    int bad = 0;
    typedef __typeof__(::expf)* expf_fn;
    expf_fn volatile ref_expf = &::expf;
    for (int l = 0; l < 16; ++l) {
        const float got = e[l];
        const float want = ref_expf(power[l]);
        if (run[l] != 0 && __builtin_bit_cast(unsigned int, got) != __builtin_bit_cast(unsigned int, want))
            ++bad;
    }
    return bad;
#endif
