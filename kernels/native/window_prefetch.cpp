// kernels/corr/window_cpu.py, prefetch_window_cpu: touches the cache lines of pixel p's SIDE + 1 tap rows
// (__builtin_prefetch, a hint: no value changes). Empty on CUDA. Template parameter SIDE = 2r + 1.

#if !defined(__CUDA_ARCH__)
    const int side = @SIDE@;
    const int height = s.shape[1];
    const int width = s.shape[2];
    const char* slice = reinterpret_cast<const char*>(s.data) + (long long)p * s.strides[0];
    const int first_col = col0 < 0 ? 0 : (col0 >= width ? width - 1 : col0);
    const int last_col = col0 + side < 0 ? 0 : (col0 + side >= width ? width - 1 : col0 + side);
    for (int t = 0; t <= side; ++t) {
        const int row = row0 + t;
        if (row < 0 || row >= height)
            continue;
        const char* taps_row = slice + (long long)row * s.strides[1];
        const char* last = taps_row + (long long)last_col * s.strides[2];
        for (const char* at = taps_row + (long long)first_col * s.strides[2]; at < last; at += 64)
            __builtin_prefetch(at);
        __builtin_prefetch(last);
    }
#endif
