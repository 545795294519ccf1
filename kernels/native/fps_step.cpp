// kernels/points/sampling.py, fps_step_f32: one block's share of a farthest-point sampling step
// (float32, CPU), the work of `_step_kernel` for block b = points lo .. hi - 1, written as plain loops
// that clang runs in vector lanes. With l = points[last]:
//   pass 1:  d_i = min(d_i, d2(p_i, l)),  d2 = (x_i - l_x)^2 + (y_i - l_y)^2 + (z_i - l_z)^2 in that
//            order, each difference, product and sum its own statement as Warp's code for sq_dist
//            (kernels/points/grid.py) has them, so no multiply-add is fused here where Warp has none,
//            and min as wp::min itself: the same d_i bits;
//   pass 2:  m = max_i d_i, then the first i with d_i = m, looked for 16 points at a time:
//            best[b] = m, best_i[b] = i, what the strict `>` scan gives (the largest value, at its
//            first index). Every d_i is +0 or a positive float no larger than FLT_MAX (d_i starts
//            at FLT_MAX, d2 >= +0, and wp::min keeps d_i where d2 is NaN), so the maximum is one value
//            with one bit pattern and the first i equal to it is the scan's index. The maximum is
//            taken with fmaxf, which clang reduces in vector lanes; a `>` select it keeps scalar
//            (with a NaN its order would matter), which made the whole step about twice as slow.
// points (N, 3) and mind (N,) are C-contiguous. Does nothing on CUDA, where the plain kernel runs.

#if !defined(__CUDA_ARCH__)
    const float* __restrict__ p = (const float*)points.data;
    float* __restrict__ d = (float*)mind.data;
    const float lx = p[3 * (long long)last];
    const float ly = p[3 * (long long)last + 1];
    const float lz = p[3 * (long long)last + 2];

    // pass 1: the distance to the last sample, and the running minimum
    for (int i = lo; i < hi; ++i) {
        const float dx = p[3 * (long long)i] - lx;
        const float dy = p[3 * (long long)i + 1] - ly;
        const float dz = p[3 * (long long)i + 2] - lz;
        const float xx = dx * dx;
        const float yy = dy * dy;
        const float zz = dz * dz;
        const float xy = xx + yy;
        const float d2 = xy + zz;
        d[i] = wp::min(d[i], d2);
    }

    // pass 2: the block's maximum, then its first index (the first group of 16 that holds it, then
    // the first point of that group)
    float top = d[lo];
    for (int i = lo + 1; i < hi; ++i)
        top = __builtin_fmaxf(top, d[i]);
    int top_i = lo;
    for (int g = lo; g < hi; g += 16) {
        const int end = g + 16 < hi ? g + 16 : hi;
        int hit = 0;
        for (int i = g; i < end; ++i)
            hit |= d[i] == top;
        if (hit) {
            top_i = g;
            while (d[top_i] != top)
                ++top_i;
            break;
        }
    }
    float* out = (float*)best.data;
    int* out_i = (int*)best_i.data;
    out[b] = top;
    out_i[b] = top_i;
#endif
