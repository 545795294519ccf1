// kernels/corr/window_cpu.py, sample_lanes_cpu / sample_patch_lanes_cpu: window_sample.cpp's statements
// on LANES consecutive pixels p0 .. p0 + LANES - 1, a pixel a clang vector lane, with each pixel's window
// origin and fractions computed as _common.pixel_window does (u = x scale - 1/2 - r, i = floor(u),
// fx = u - i), so each output channel's LANES samples leave in one vector store. Template parameters:
// SIDE = 2r + 1, LANES, FROM_PATCH (1: the windows are read from each pixel's on-the-fly patch, origin
// (0, 0); 0: from the level slice at the window's origin).

    typedef decltype(scale) T;
    typedef T V __attribute__((ext_vector_type(@LANES@)));
    const int side = @SIDE@;
    const T radius = T((@SIDE@ - 1) / 2);
    const int height = s.shape[1];
    const int width = s.shape[2];
    const int frame_width = coords.shape[2];
    const long long row_stride = s.strides[1];
    const long long col_stride = s.strides[2];
    const long long out_stride = out.strides[0];
    const char* xy = reinterpret_cast<const char*>(coords.data);
    V fx, fy;
    typedef decltype(fx < fy) M;  // lane masks: integers as wide as T
    int row0[@LANES@], col0[@LANES@];
    const char* slice[@LANES@];
    long long pixel_offset[@LANES@];  // of out[0, h, w]
    // one axis of a pixel's window from its coordinate x: u = x scale - 1/2 - r, the origin floor(u) (0 when
    // the window is read from the pixel's patch) in `origin`, the fraction u - floor(u) returned
    auto window_axis = [&](const char* coord, int& origin) {
        T u = *reinterpret_cast<const T*>(coord) * scale;
        u = u - T(0.5);
        u = u - radius;
        const T i = wp::floor(u);
#if @FROM_PATCH@
        origin = 0;
#else
        origin = (int)i;
#endif
        return u - i;
    };
    _Pragma("unroll") for (int l = 0; l < @LANES@; ++l) {
        const int p = p0 + l;
        const int h = p / frame_width;
        const int w = p % frame_width;
        const long long at = (long long)h * coords.strides[1] + (long long)w * coords.strides[2];
        fx[l] = window_axis(xy + at, col0[l]);
        fy[l] = window_axis(xy + coords.strides[0] + at, row0[l]);
        slice[l] = reinterpret_cast<const char*>(s.data) + (long long)p * s.strides[0];
        pixel_offset[l] = (long long)h * out.strides[1] + (long long)w * out.strides[2];
    }
    const V one = T(1);
    const V zero = T(0);
    const V gx = one - fx;
    const V gy = one - fy;
    // out[c, p0 .. p0 + @LANES@ - 1] contiguous (a fresh output): one vector store a channel
    const bool packed = out.strides[2] == (long long)sizeof(T)
                        && pixel_offset[@LANES@ - 1] - pixel_offset[0] == (long long)(@LANES@ - 1) * sizeof(T);
    char* first = reinterpret_cast<char*>(out.data) + (long long)channel0 * out_stride;
    bool inside = col_stride == (long long)sizeof(T);
    _Pragma("unroll") for (int l = 0; l < @LANES@; ++l)
        inside = inside && row0[l] >= 0 && col0[l] >= 0 && row0[l] + side < height && col0[l] + side < width;
    long long col_offset[@SIDE@ + 1][@LANES@];
    M col_ok[@SIDE@ + 1];
    if (!inside) {
        _Pragma("unroll") for (int c = 0; c <= side; ++c) {
            _Pragma("unroll") for (int l = 0; l < @LANES@; ++l) {
                const int col = col0[l] + c;
                col_ok[c][l] = (col >= 0 && col < width) ? -1 : 0;
                col_offset[c][l] = (long long)(col < 0 ? 0 : (col >= width ? width - 1 : col)) * col_stride;
            }
        }
    }
    V top[@SIDE@];
    for (int t = 0; t <= side; ++t) {
        V taps[@SIDE@ + 1];
        if (inside) {
            const T* rows[@LANES@];
            _Pragma("unroll") for (int l = 0; l < @LANES@; ++l)
                rows[l] = reinterpret_cast<const T*>(slice[l] + (long long)(row0[l] + t) * row_stride) + col0[l];
            _Pragma("unroll") for (int c = 0; c <= side; ++c) {
                V tap;
                _Pragma("unroll") for (int l = 0; l < @LANES@; ++l)
                    tap[l] = rows[l][c];
                taps[c] = tap;
            }
        } else {
            const char* rows[@LANES@];
            M row_ok;
            _Pragma("unroll") for (int l = 0; l < @LANES@; ++l) {
                const int row = row0[l] + t;
                row_ok[l] = (row >= 0 && row < height) ? -1 : 0;
                rows[l] = slice[l] + (long long)(row < 0 ? 0 : (row >= height ? height - 1 : row)) * row_stride;
            }
            _Pragma("unroll") for (int c = 0; c <= side; ++c) {
                V tap;
                _Pragma("unroll") for (int l = 0; l < @LANES@; ++l)
                    tap[l] = *reinterpret_cast<const T*>(rows[l] + col_offset[c][l]);
                const M ok = row_ok & col_ok[c];
                taps[c] = ok != 0 ? tap : zero;
            }
        }
        _Pragma("unroll") for (int a = 0; a < side; ++a) {
            const V left = gx * taps[a];
            const V right = fx * taps[a + 1];
            const V bottom = left + right;
            if (t > 0) {
                const V upper = gy * top[a];
                const V lower = fy * bottom;
                const V sample = upper + lower;
                char* channel = first + (long long)(a * side + t - 1) * out_stride;
                if (packed) {
                    __builtin_memcpy(channel + pixel_offset[0], &sample, sizeof(V));
                } else {
                    _Pragma("unroll") for (int l = 0; l < @LANES@; ++l)
                        *reinterpret_cast<T*>(channel + pixel_offset[l]) = sample[l];
                }
            }
            top[a] = bottom;
        }
    }
