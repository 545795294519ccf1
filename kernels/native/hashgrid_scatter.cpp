// kernels/volume/hashgrid_cpu.py, hash_scatter_run_cpu: the hash encoding's table gradient (F = 2) of the
// points lo .. hi - 1 at level l: the weights of 8 points at a time, then table[row_c, j] += w_c G[n, 2 l + j]
// one point after the other, corners c = 0 .. 7, feature 0 then 1 (hashgrid._hash_backward_kernel's
// additions in its order: the same gradient bit for bit, collisions included). Plain C++.
#include "hashgrid_common.h"

    char* gb = reinterpret_cast<char*>(table.data);
    const char* gob = reinterpret_cast<const char*>(grad_out.data);
    const long long g0 = (long long)(2 * l) * grad_out.strides[1];
    const long long g1 = g0 + grad_out.strides[1];
    const long long gs0 = grad_out.strides[0];
    for (int n0 = lo; n0 < hi; n0 += K) {
#include "hashgrid_cells.h"
        T w[8][K];
        _Pragma("unroll") for (int c = 0; c < 8; ++c) {
            _Pragma("unroll") for (int k = 0; k < K; ++k) {
                w[c][k] = corner_weight(c, fx[k], fy[k], fz[k]);
            }
        }
        for (int k = 0; k < m; ++k) {
            const char* go = gob + (long long)(n0 + k) * gs0;
            const T a0 = *reinterpret_cast<const T*>(go + g0);
            const T a1 = *reinterpret_cast<const T*>(go + g1);
            _Pragma("unroll") for (int c = 0; c < 8; ++c) {
                char* r = gb + (long long)row[c][k] * ts0;
                T* t0 = reinterpret_cast<T*>(r);
                T* t1 = reinterpret_cast<T*>(r + ts1);
                const T p0 = w[c][k] * a0;
                *t0 = *t0 + p0;
                const T p1 = w[c][k] * a1;
                *t1 = *t1 + p1;
            }
        }
    }
