// kernels/corr/window_cpu.py, sample_window_cpu: the bilinear window of one pixel p (the dense lookup's
// (3)-(4)): with gx = 1 - fx, gy = 1 - fy and tap rows t of s[p] (taps outside read 0),
// R[t, a] = gx S[row0 + t, col0 + a] + fx S[row0 + t, col0 + a + 1] and
// out[channel0 + a SIDE + b, h, w] = gy R[b, a] + fy R[b + 1, a], each product and sum its own statement,
// as Warp's generated code computes _common.sample_window. Template parameter SIDE = 2r + 1.

    typedef decltype(fx) T;
    const int side = @SIDE@;
    const T one = T(1);
    const T zero = T(0);
    const T gx = one - fx;
    const T gy = one - fy;
    const int height = s.shape[1];
    const int width = s.shape[2];
    const char* slice = reinterpret_cast<const char*>(s.data) + (long long)p * s.strides[0];
    const long long row_stride = s.strides[1];
    const long long col_stride = s.strides[2];
    const long long out_stride = out.strides[0];
    // out[channel0 + a side + b, h, w] lies at first + b out_stride + a column_step
    char* first = reinterpret_cast<char*>(out.data) + (long long)h * out.strides[1]
                  + (long long)w * out.strides[2] + (long long)channel0 * out_stride;
    const long long column_step = (long long)side * out_stride;
    // every tap inside s[p] and its columns contiguous: rows of taps read without tests
    const bool inside = row0 >= 0 && col0 >= 0 && row0 + side < height && col0 + side < width
                        && col_stride == (long long)sizeof(T);
    long long col_offset[@SIDE@ + 1];
    bool col_ok[@SIDE@ + 1];
    if (!inside) {
        // taps outside s[p] read 0: each tap column's test and clamped offset, once
        for (int c = 0; c <= side; ++c) {
            const int col = col0 + c;
            col_ok[c] = col >= 0 && col < width;
            col_offset[c] = (long long)(col < 0 ? 0 : (col >= width ? width - 1 : col)) * col_stride;
        }
    }
    T taps[@SIDE@ + 1];
    T top[@SIDE@];     // row samples R[t - 1, .]
    T bottom[@SIDE@];  // row samples R[t, .]
    for (int t = 0; t <= side; ++t) {
        const int row = row0 + t;
        if (inside) {
            const T* taps_row = reinterpret_cast<const T*>(slice + (long long)row * row_stride) + col0;
            for (int c = 0; c <= side; ++c)
                taps[c] = taps_row[c];
        } else {
            const bool row_ok = row >= 0 && row < height;
            const char* taps_row = slice + (long long)(row < 0 ? 0 : (row >= height ? height - 1 : row)) * row_stride;
            for (int c = 0; c <= side; ++c) {
                const T tap = *reinterpret_cast<const T*>(taps_row + col_offset[c]);
                taps[c] = (row_ok && col_ok[c]) ? tap : zero;
            }
        }
        for (int a = 0; a < side; ++a) {
            const T left = gx * taps[a];
            const T right = fx * taps[a + 1];
            bottom[a] = left + right;
        }
        if (t > 0) {
            char* o = first + (long long)(t - 1) * out_stride;
            for (int a = 0; a < side; ++a) {
                const T upper = gy * top[a];
                const T lower = fy * bottom[a];
                *reinterpret_cast<T*>(o) = upper + lower;
                o += column_step;
            }
        }
        for (int a = 0; a < side; ++a)
            top[a] = bottom[a];
    }
