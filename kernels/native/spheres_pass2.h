// kernels/volume/spheres_cpu.py, pass 2 on one group: from the falloffs F[j K + k],
// sigma = ((0 + s_0 F_0) + s_1 F_1) + ... and the compositing exponent -(sigma delta_j) into out2[j];
// spheres_passes._spheres_dense_factor_kernel's float32 operations in its order.

  {
    const char* lb = (const char*)delta.data;
    const long long ls0 = delta.strides[0];
    const long long ls1 = delta.strides[1];
    for (int j = 0; j < n_s; ++j) {
        const v8f dk = lanes_at(lb, ls0, ls1, j);
        v8f sig = 0.0f;
        for (int k = 0; k < n_k; ++k) {
            const v8f d = P[4 * k + 3] * F[j * n_k + k];
            sig = sig + d;
        }
        const v8f x = sig * dk;
        out2[j] = -x;
    }
  }
