// kernels/stereo/adcensus_kernels.py, _cells16: the 16 cost cells (x, d0 + i) of a float32 volume whose lanes
// are all in range: rho_census[popcount(a ^ cr[y, u - i])] + rho_grad[i] (+ rho_bt[i]), stored; the
// fused kernel's lane loop with its operations in its order (contraction off on the CPU).

#if !defined(__CUDA_ARCH__)
#pragma clang fp contract(off)
#endif
    float total[16];
    for (int l = 0; l < 16; ++l)
        total[l] = wp::index(rho, (int)wp::bit_count(a ^ wp::index(cr, y, u - l)));
    for (int l = 0; l < 16; ++l)
        total[l] = total[l] + rg.c[l];
    if (terms > 1)
        for (int l = 0; l < 16; ++l)
            total[l] = total[l] + rb.c[l];
    for (int l = 0; l < 16; ++l)
        wp::index(out, y, x, k0 + l) = total[l];
    return 0;
