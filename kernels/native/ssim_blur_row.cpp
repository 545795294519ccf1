// kernels/ssim.py, blur_row_f32: one row of one map of the SSIM filter's 1-D Gaussian correlation
// (float32, CPU; HALF = the window's half width), written as a sum of shifted rows so that the
// compiler runs it in vector lanes.
// Output pixel p of row `row` of map m is sum_k taps[k] src[m, .., p + (k - HALF) along `axis`, ..] over
// the k whose source pixel lies inside the image (zero padding), accumulated from 0 in increasing k:
// the same terms in the same order as _blur_kernel's loop, each product and sum its own statement
// (so a fused multiply-add happens here exactly where it happens there), hence the same bits.
// axis 2: along the columns (a row's W*C values, channel fastest, shifted by whole pixels);
// axis 1: along the rows (whole rows of W*C values added). src and dst are C-contiguous (M, H, W, C).

    const int h = src.shape[1];
    const int w = src.shape[2];
    const int c = src.shape[3];
    const int n = w * c;
    const int half = @HALF@;
    const float* tp = (const float*)taps.data;
    float* out = (float*)((char*)dst.data + (size_t)m * dst.strides[0] + (size_t)row * dst.strides[1]);
    const char* map = (const char*)src.data + (size_t)m * src.strides[0];
    for (int j = 0; j < n; ++j)
        out[j] = 0.0f;
    for (int k = 0; k < 2 * half + 1; ++k) {
        const float t = tp[k];
        if (axis == 2) {
            // output columns whose source column col + k - half lies in [0, w)
            const int lo = (k < half ? half - k : 0) * c;
            const int hi = (k > half ? w + half - k : w) * c;
            const float* in = (const float*)(map + (size_t)row * src.strides[1]) + (k - half) * c;
            for (int j = lo; j < hi; ++j) {
                const float p = t * in[j];
                out[j] = out[j] + p;
            }
        } else {
            const int r = row + k - half;
            if (r < 0 || r >= h)
                continue;
            const float* in = (const float*)(map + (size_t)r * src.strides[1]);
            for (int j = 0; j < n; ++j) {
                const float p = t * in[j];
                out[j] = out[j] + p;
            }
        }
    }
