// kernels/volume/spheres_cpu.py, _spheres_cpu_available: 1 where the spheres' C++ passes are compiled
// to do their work (a CPU target with AVX2), else 0 (CUDA, other CPUs).

#if defined(__CUDA_ARCH__) || !defined(__AVX2__)
    return 0;
#else
    return 1;
#endif
