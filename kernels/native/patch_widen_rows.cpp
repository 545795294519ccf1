// kernels/corr/patch_cpu.py, widen_row_float16_cpu: row n of x (float16, C8 channels, a multiple of 8)
// widened to float32 into out by 8-lane vector conversions (exact).

    typedef _Float16 S;
    typedef float T;
    typedef S SV __attribute__((ext_vector_type(8), aligned(sizeof(S))));
    typedef T V __attribute__((ext_vector_type(8), aligned(sizeof(T))));
    const int n_vec = x.shape[1] / 8;
    const SV* in = reinterpret_cast<const SV*>(reinterpret_cast<const char*>(x.data) + (long long)n * x.strides[0]);
    V* o = reinterpret_cast<V*>(reinterpret_cast<char*>(out.data) + (long long)n * out.strides[0]);
    for (int k = 0; k < n_vec; ++k)
        o[k] = __builtin_convertvector(in[k], V);
