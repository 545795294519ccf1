// kernels/volume/spheres_cpu.py, pass 3 on one group: from the falloffs F and the factors E[j], per
// sample d_k = s_k F_k, sigma and the colour sums n += d_k col_k from 0 in sphere order, the colour
// divided by sigma where sigma > 1e-6, early termination (T < t_threshold), one blend8.h step; then the
// pixels C + T b, depth and 1 - T. spheres_passes._spheres_dense_composite_kernel's float32 operations.

  {
    const v8f thr = t_threshold;
    const v8f one = 1.0f;
    const v8f eps = 1e-6f;
    v8f T = one;
    v8f cr = 0.0f;
    v8f cg = 0.0f;
    v8f cb = 0.0f;
    v8f dep = 0.0f;
    for (int j = 0; j < n_s; ++j) {
        const v8i run = ~(T < thr);
        if (!__builtin_reduce_or(run))
            break;

        const v8f tk = lanes_at(tb, ts0, ts1, j);

        v8f sig = 0.0f;
        v8f nr = 0.0f;
        v8f ng = 0.0f;
        v8f nb = 0.0f;
        for (int k = 0; k < n_k; ++k) {
            const v8f d = P[4 * k + 3] * F[j * n_k + k];
            sig = sig + d;
            const v8f d0 = d * P[4 * k];
            nr = nr + d0;
            const v8f d1 = d * P[4 * k + 1];
            ng = ng + d1;
            const v8f d2 = d * P[4 * k + 2];
            nb = nb + d2;
        }
        const v8i norm = sig > eps;
        const v8f qr = nr / sig;
        const v8f qg = ng / sig;
        const v8f qb = nb / sig;
        nr = sel(norm, qr, nr);
        ng = sel(norm, qg, ng);
        nb = sel(norm, qb, nb);
        blend8(run, E[j], nr, ng, nb, tk, T, cr, cg, cb, dep);
    }
    const float* bg = (const float*)background.data;
    const float b0 = bg[0];
    const float b1 = bg[1];
    const float b2 = bg[2];
    char* rb = (char*)out_rgb.data;
    const long long rs0 = out_rgb.strides[0], rs1 = out_rgb.strides[1];
    for (int l = 0; l < 8; ++l) {
        const int r = 8 * g + l;
        if (r >= n_rays)
            break;
        const float Tl = T[l];
        const float tb0 = Tl * b0;
        const float tb1 = Tl * b1;
        const float tb2 = Tl * b2;
        char* o = rb + (long long)r * rs0;
        *(float*)o = cr[l] + tb0;
        *(float*)(o + rs1) = cg[l] + tb1;
        *(float*)(o + 2 * rs1) = cb[l] + tb2;
        *(float*)((char*)out_depth.data + (long long)r * out_depth.strides[0]) = dep[l];
        *(float*)((char*)out_opacity.data + (long long)r * out_opacity.strides[0]) = 1.0f - Tl;
    }
  }
