// kernels/corr/patch_cpu.py, onthefly_group_cpu: the on-the-fly lookup's patches of one pixel group g
// (pixels whose windows share the column origin g - SIDE), level row by level row, up to 8 pixels at a
// time sharing each converted tap vector (pairs of pixels in 16-lane vectors):
// acc = x_0 y_0, acc = acc + x_k y_k (k = 1, 2, ...), T = (((acc[0] + acc[1]) + ...) + acc[7]) inv,
// 0 outside the level; onthefly_kernels._patch_row's operations in its order. Template parameters: SIDE = 2r + 2
// (taps a patch row), STORE (the stored features' C type: float, double or _Float16), FUSED (1: each
// step one fused multiply-add, exact for float16 storage with float32 work; 0: a product, then a sum).

    typedef decltype(inv) T;
    typedef @STORE@ S;
    typedef T V __attribute__((ext_vector_type(8)));
    typedef T XV __attribute__((ext_vector_type(8), aligned(sizeof(T))));
    typedef S SV __attribute__((ext_vector_type(8), aligned(sizeof(S))));
    const int side = @SIDE@;  // taps a patch row: 2r + 2 (even)
    const int half = @SIDE@ / 2;
    const int n_vec = f1.shape[1] / 8;
    const int height = height_l;
    const int width = width_l;
    const int* ord = reinterpret_cast<const int*>(order.data);
    const int* gj0 = reinterpret_cast<const int*>(j0s.data);
    const int q0 = reinterpret_cast<const int*>(starts.data)[g];
    const int q1 = reinterpret_cast<const int*>(starts.data)[g + 1];
    const int col0 = g - side;  // the bucket's window column origin (clamped to [-side, width]: see patch_group_pixels.cpp)
    const char* level = reinterpret_cast<const char*>(f2l.data);
    const long long tap_stride = f2l.strides[0];
    const char* f1_base = reinterpret_cast<const char*>(f1.data);
    const long long f1_stride = f1.strides[0];
    char* patch_base = reinterpret_cast<char*>(patch.data);
    const long long patch_pixel = patch.strides[0];
    const long long patch_row = patch.strides[1];
    const long long col_step = patch.strides[2] / (long long)sizeof(T);
    const T zero = T(0.0);
    const T outside = inv * zero;  // `_tap_or_zero`'s 0
    long long col_offset[@SIDE@];
    bool col_ok[@SIDE@];
    _Pragma("unroll") for (int c = 0; c < side; ++c) {
        const long long col = (long long)col0 + c;
        col_ok[c] = col >= 0 && col < width;
        col_offset[c] = (col < 0 ? 0 : (col >= width ? width - 1 : col)) * tap_stride;
    }
    const bool any_col = (long long)col0 + side > 0 && col0 < width;
    // rows outside the level: 0; a window with every column outside: `outside` in its rows inside
    for (int q = q0; q < q1; ++q) {
        char* patch_p = patch_base + (long long)ord[q] * patch_pixel;
        for (int ty = 0; ty < side; ++ty) {
            const long long row = (long long)gj0[q] + ty;
            const bool row_in = row >= 0 && row < height;
            if (row_in && any_col)
                continue;
            T* out_row = reinterpret_cast<T*>(patch_p + (long long)ty * patch_row);
            _Pragma("unroll") for (int c = 0; c < side; ++c)
                out_row[c * col_step] = row_in ? outside : zero;
        }
    }
    if (!any_col || q0 >= q1)
        return;
    // a tap row's side 8-lane accumulators summed lane by lane, scaled and stored (`outside` where the column
    // is outside the level); taps 0..7: the 8x8 transpose of their accumulators, B[q][c] = acc[c][q], so the
    // lane sums ((acc[c][0] + acc[c][1]) + ...) + acc[c][7] run as 7 vector additions, the same additions in
    // the same order for every tap
    auto store_row = [&](const V* acc, T* out_row) {
        int c0 = 0;
        if (@SIDE@ >= 8 && col_step == 1) {
            V P[8], Q[8], B[8];
            _Pragma("unroll") for (int i = 0; i < 4; ++i) {
                P[2 * i] = __builtin_shufflevector(acc[2 * i], acc[2 * i + 1], 0, 8, 2, 10, 4, 12, 6, 14);
                P[2 * i + 1] = __builtin_shufflevector(acc[2 * i], acc[2 * i + 1], 1, 9, 3, 11, 5, 13, 7, 15);
            }
            _Pragma("unroll") for (int j = 0; j < 2; ++j) {
                _Pragma("unroll") for (int e = 0; e < 2; ++e) {
                    const V a = P[4 * j + e];
                    const V b = P[4 * j + 2 + e];
                    Q[4 * j + e] = __builtin_shufflevector(a, b, 0, 1, 8, 9, 4, 5, 12, 13);
                    Q[4 * j + 2 + e] = __builtin_shufflevector(a, b, 2, 3, 10, 11, 6, 7, 14, 15);
                }
            }
            _Pragma("unroll") for (int m = 0; m < 4; ++m) {
                const int q = (m & 1) + 2 * (m >> 1);
                B[q] = __builtin_shufflevector(Q[m], Q[4 + m], 0, 1, 2, 3, 8, 9, 10, 11);
                B[q + 4] = __builtin_shufflevector(Q[m], Q[4 + m], 4, 5, 6, 7, 12, 13, 14, 15);
            }
            V sum = B[0];
            _Pragma("unroll") for (int q = 1; q < 8; ++q)
                sum = sum + B[q];
            const V taps = sum * inv;
            V kept;
            _Pragma("unroll") for (int c = 0; c < 8; ++c)
                kept[c] = col_ok[c] ? taps[c] : outside;
            __builtin_memcpy(out_row, &kept, sizeof(V));
            c0 = 8;
        }
        // the other taps one at a time (constant bounds, so the loop unrolls: c0 is 0 or 8)
        _Pragma("unroll") for (int c = 0; c < side; ++c) {
            if (c < c0)
                continue;
            T s = acc[c][0];
            _Pragma("unroll") for (int q = 1; q < 8; ++q)
                s = s + acc[c][q];
            const T tap = s * inv;
            out_row[c * col_step] = col_ok[c] ? tap : outside;
        }
    };
    // one accumulation step acc + x y, lane by lane (8 or 16 lanes): one fused multiply-add (FUSED), else
    // the product, then the sum
    auto step = [](auto x, auto y, auto acc) {
#if @FUSED@
        return __builtin_elementwise_fma(x, y, acc);
#else
        const auto prod = x * y;
        return acc + prod;
#endif
    };
    // K pixels (sorted positions q .. q + K - 1; K = 1 here) against level row r: their tap rows r - j0,
    // half a row's taps at a time, each tap vector converted once for the K pixels
    auto block = [&](auto tag, int q, long long r) {
        constexpr int K = sizeof(*tag);
        const char* base = level + r * width * tap_stride;
        const XV* xs[K];
        _Pragma("unroll") for (int i = 0; i < K; ++i)
            xs[i] = reinterpret_cast<const XV*>(f1_base + (long long)ord[q + i] * f1_stride);
        V acc[K][@SIDE@];
        _Pragma("unroll") for (int h = 0; h < 2; ++h) {
            const SV* ys[@SIDE@ / 2];
            _Pragma("unroll") for (int c = 0; c < half; ++c)
                ys[c] = reinterpret_cast<const SV*>(base + col_offset[h * half + c]);
            V a[K][@SIDE@ / 2];
            {
                V y[@SIDE@ / 2];
                _Pragma("unroll") for (int c = 0; c < half; ++c)
                    y[c] = __builtin_convertvector(ys[c][0], V);
                _Pragma("unroll") for (int i = 0; i < K; ++i) {
                    const V x = xs[i][0];
                    _Pragma("unroll") for (int c = 0; c < half; ++c)
                        a[i][c] = x * y[c];
                }
            }
            for (int k = 1; k < n_vec; ++k) {
                V y[@SIDE@ / 2];
                _Pragma("unroll") for (int c = 0; c < half; ++c)
                    y[c] = __builtin_convertvector(ys[c][k], V);
                _Pragma("unroll") for (int i = 0; i < K; ++i) {
                    const V x = xs[i][k];
                    _Pragma("unroll") for (int c = 0; c < half; ++c)
                        a[i][c] = step(x, y[c], a[i][c]);
                }
            }
            _Pragma("unroll") for (int i = 0; i < K; ++i)
                _Pragma("unroll") for (int c = 0; c < half; ++c)
                    acc[i][h * half + c] = a[i][c];
        }
        _Pragma("unroll") for (int i = 0; i < K; ++i) {
            const long long ty = r - gj0[q + i];
            store_row(acc[i], reinterpret_cast<T*>(patch_base + (long long)ord[q + i] * patch_pixel + ty * patch_row));
        }
    };
    // 2P pixels as P pairs, a pair in the two halves of a 16-lane vector (lanes 0-7 the first pixel's, 8-15
    // the second's) against the tap vector in both halves: each lane the same operations as `block`'s
    typedef T W2 __attribute__((ext_vector_type(16)));
    auto pairs = [&](auto tag, int q, long long r) {
        constexpr int P = sizeof(*tag);
        const char* base = level + r * width * tap_stride;
        const XV* xs[2 * P];
        _Pragma("unroll") for (int i = 0; i < 2 * P; ++i)
            xs[i] = reinterpret_cast<const XV*>(f1_base + (long long)ord[q + i] * f1_stride);
        V acc[2 * P][@SIDE@];
        _Pragma("unroll") for (int h = 0; h < 2; ++h) {
            const SV* ys[@SIDE@ / 2];
            _Pragma("unroll") for (int c = 0; c < half; ++c)
                ys[c] = reinterpret_cast<const SV*>(base + col_offset[h * half + c]);
            W2 a[P][@SIDE@ / 2];
            {
                W2 y[@SIDE@ / 2];
                _Pragma("unroll") for (int c = 0; c < half; ++c) {
                    const V y8 = __builtin_convertvector(ys[c][0], V);
                    y[c] = __builtin_shufflevector(y8, y8, 0, 1, 2, 3, 4, 5, 6, 7, 0, 1, 2, 3, 4, 5, 6, 7);
                }
                _Pragma("unroll") for (int i = 0; i < P; ++i) {
                    const V x0 = xs[2 * i][0];
                    const V x1 = xs[2 * i + 1][0];
                    const W2 x = __builtin_shufflevector(x0, x1, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
                    _Pragma("unroll") for (int c = 0; c < half; ++c)
                        a[i][c] = x * y[c];
                }
            }
            for (int k = 1; k < n_vec; ++k) {
                W2 y[@SIDE@ / 2];
                _Pragma("unroll") for (int c = 0; c < half; ++c) {
                    const V y8 = __builtin_convertvector(ys[c][k], V);
                    y[c] = __builtin_shufflevector(y8, y8, 0, 1, 2, 3, 4, 5, 6, 7, 0, 1, 2, 3, 4, 5, 6, 7);
                }
                _Pragma("unroll") for (int i = 0; i < P; ++i) {
                    const V x0 = xs[2 * i][k];
                    const V x1 = xs[2 * i + 1][k];
                    const W2 x = __builtin_shufflevector(x0, x1, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
                    _Pragma("unroll") for (int c = 0; c < half; ++c)
                        a[i][c] = step(x, y[c], a[i][c]);
                }
            }
            _Pragma("unroll") for (int i = 0; i < P; ++i)
                _Pragma("unroll") for (int c = 0; c < half; ++c) {
                    const W2 pair = a[i][c];
                    acc[2 * i][h * half + c] = __builtin_shufflevector(pair, pair, 0, 1, 2, 3, 4, 5, 6, 7);
                    acc[2 * i + 1][h * half + c] = __builtin_shufflevector(pair, pair, 8, 9, 10, 11, 12, 13, 14, 15);
                }
        }
        _Pragma("unroll") for (int i = 0; i < 2 * P; ++i) {
            const long long ty = r - gj0[q + i];
            store_row(acc[i], reinterpret_cast<T*>(patch_base + (long long)ord[q + i] * patch_pixel + ty * patch_row));
        }
    };
    // level rows in order; the pixels whose windows hold row r are q in [lo, hi) (sorted by j0)
    const long long r_first = (long long)gj0[q0] > 0 ? (long long)gj0[q0] : 0;
    const long long r_last_win = (long long)gj0[q1 - 1] + side - 1;
    const long long r_last = r_last_win < height - 1 ? r_last_win : height - 1;
    int lo = q0;
    int hi = q0;
    for (long long r = r_first; r <= r_last; ++r) {
        while (hi < q1 && (long long)gj0[hi] <= r)
            ++hi;
        while (lo < hi && (long long)gj0[lo] + side - 1 < r)
            ++lo;
        int q = lo;
        for (; q + 8 <= hi; q += 8)
            pairs((const char(*)[4])nullptr, q, r);
        if (q + 4 <= hi) {
            pairs((const char(*)[2])nullptr, q, r);
            q += 4;
        }
        if (q + 2 <= hi) {
            pairs((const char(*)[1])nullptr, q, r);
            q += 2;
        }
        if (q < hi)
            block((const char(*)[1])nullptr, q, r);
    }
