// kernels/splat/rowblend.py, _rowblend_available: 1 where rowblend.cpp is compiled to do its work (a CPU
// target with AVX2 and FMA), else 0.

#if defined(__CUDA_ARCH__) || !defined(__AVX2__) || !defined(__FMA__)
    return 0;
#else
    return 1;
#endif
