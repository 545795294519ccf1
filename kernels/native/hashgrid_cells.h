// kernels/volume/hashgrid_cpu.py: the cells, fractions and table rows of the points n0 .. n0 + m - 1 in K
// lanes (a short last group repeats its first point): u = x N_l, i = clamp(floor(u), 0, N_l - 1),
// f = u - i per axis; row_c the level's dense index or spatial hash (x ^ y 2654435761 ^ z 805459861,
// masked) of corner c = 0 .. 7, as hashgrid.hash_index computes them.

        const int m = hi - n0 < K ? hi - n0 : K;
        int ix[K], iy[K], iz[K];
        T fx[K], fy[K], fz[K];
        _Pragma("unroll") for (int k = 0; k < K; ++k) {
            const long long n = n0 + (k < m ? k : 0);
            const T ux = *reinterpret_cast<const T*>(xb + n * xs1) * rf;
            const T uy = *reinterpret_cast<const T*>(xb + xs0 + n * xs1) * rf;
            const T uz = *reinterpret_cast<const T*>(xb + 2 * xs0 + n * xs1) * rf;
            const int a = wp::clamp((int)wp::floor(ux), 0, res - 1);
            const int b = wp::clamp((int)wp::floor(uy), 0, res - 1);
            const int c = wp::clamp((int)wp::floor(uz), 0, res - 1);
            ix[k] = a;
            iy[k] = b;
            iz[k] = c;
            fx[k] = ux - T(a);
            fy[k] = uy - T(b);
            fz[k] = uz - T(c);
        }
        int row[8][K];
        if (dense) {
            _Pragma("unroll") for (int c = 0; c < 8; ++c) {
                _Pragma("unroll") for (int k = 0; k < K; ++k) {
                    row[c][k] = base + ((ix[k] + (c & 1))
                                        + r1 * ((iy[k] + ((c >> 1) & 1)) + r1 * (iz[k] + ((c >> 2) & 1))));
                }
            }
        } else {
            _Pragma("unroll") for (int c = 0; c < 8; ++c) {
                _Pragma("unroll") for (int k = 0; k < K; ++k) {
                    const unsigned int h = (unsigned int)(ix[k] + (c & 1))
                                           ^ ((unsigned int)(iy[k] + ((c >> 1) & 1)) * 2654435761u)
                                           ^ ((unsigned int)(iz[k] + ((c >> 2) & 1)) * 805459861u);
                    row[c][k] = base + (int)(h & mask);
                }
            }
        }
