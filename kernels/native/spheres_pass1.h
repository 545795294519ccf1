// kernels/volume/spheres_cpu.py, pass 1 on one group of eight rays: x = o + (t_j d), for sphere k
// q = ((x - c_k)_x^2 + (x - c_k)_y^2) + (x - c_k)_z^2, m = max(0, sqrt(q) - r_k) (Warp's max: 0 if
// 0 > v, else v), the exponent -s_k m into out1[j K + k]; spheres_passes._spheres_dense_exponent_kernel's
// float32 operations in its order.

  {
    const char* ob = (const char*)origins.data;
    const char* db = (const char*)dirs.data;
    const long long os0 = origins.strides[0], os1 = origins.strides[1];
    const long long ds0 = dirs.strides[0], ds1 = dirs.strides[1];
    v8f ox, oy, oz, dx, dy, dz;
    for (int l = 0; l < 8; ++l) {
        const char* o = ob + (long long)rl[l] * os0;
        const char* d = db + (long long)rl[l] * ds0;
        ox[l] = *(const float*)o;
        oy[l] = *(const float*)(o + os1);
        oz[l] = *(const float*)(o + 2 * os1);
        dx[l] = *(const float*)d;
        dy[l] = *(const float*)(d + ds1);
        dz[l] = *(const float*)(d + 2 * ds1);
    }
    const v8f zero = 0.0f;
    for (int j = 0; j < n_s; ++j) {

        const v8f tk = lanes_at(tb, ts0, ts1, j);

        const v8f sx = tk * dx;
        const v8f sy = tk * dy;
        const v8f sz = tk * dz;
        const v8f px = ox + sx;
        const v8f py = oy + sy;
        const v8f pz = oz + sz;
        for (int k = 0; k < n_k; ++k) {
            const v8f ex = px - G[4 * k];
            const v8f ey = py - G[4 * k + 1];
            const v8f ez = pz - G[4 * k + 2];
            const v8f qx = ex * ex;
            const v8f qy = ey * ey;
            const v8f qz = ez * ez;
            const v8f qxy = qx + qy;
            const v8f q = qxy + qz;
            const v8f dist = __builtin_elementwise_sqrt(q);
            const v8f v = dist - G[4 * k + 3];
            const v8i pos = zero > v;
            const v8f m = sel(pos, zero, v);
            const float neg_s = -P[4 * k + 3];
            out1[j * n_k + k] = neg_s * m;
        }
    }
  }
