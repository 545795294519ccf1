// kernels/volume/hashgrid_cpu.py, hash_encode_run_cpu: the hash encoding forward (F = 2) of the points
// lo .. hi - 1 at level l, 8 at a time: w_c = (w_x w_y) w_z, enc[2 l + j, n] = (...((0 + w_0 t_0j) +
// w_1 t_1j) + ...) + w_7 t_7j, each product and sum its own statement (hashgrid._hash_forward_kernel's
// operations in its order, so the same bits).
#include "hashgrid_common.h"

    for (int n0 = lo; n0 < hi; n0 += K) {
#include "hashgrid_cells.h"
        T s0[K], s1[K];
        _Pragma("unroll") for (int k = 0; k < K; ++k) {
            s0[k] = T(0);
            s1[k] = T(0);
        }
        _Pragma("unroll") for (int c = 0; c < 8; ++c) {
            _Pragma("unroll") for (int k = 0; k < K; ++k) {
                const T w = corner_weight(c, fx[k], fy[k], fz[k]);
                const char* r = tb + (long long)row[c][k] * ts0;
                const T t0 = *reinterpret_cast<const T*>(r);
                const T t1 = *reinterpret_cast<const T*>(r + ts1);
                const T p0 = w * t0;
                const T p1 = w * t1;
                s0[k] = s0[k] + p0;
                s1[k] = s1[k] + p1;
            }
        }
        char* ob = reinterpret_cast<char*>(out.data);
        const long long os1 = out.strides[1];
        char* o0 = ob + (long long)(2 * l) * out.strides[0];
        char* o1 = o0 + out.strides[0];
        for (int k = 0; k < m; ++k) {
            *reinterpret_cast<T*>(o0 + (long long)(n0 + k) * os1) = s0[k];
            *reinterpret_cast<T*>(o1 + (long long)(n0 + k) * os1) = s1[k];
        }
    }
