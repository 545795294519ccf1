// The set-up shared by kernels/volume/hashgrid_cpu.py's encode and scatter (hashgrid_encode.cpp,
// hashgrid_scatter.cpp): the float type T, K = 8 points a step, the strides of x and the table, the
// level's resolution and its rows base = l table_size; corner_weight(c, fx, fy, fz), the trilinear weight
// (w_x w_y) w_z of cell corner c (bit 0, 1, 2: the upper x, y, z) at the fractions (fx, fy, fz).

    typedef decltype(zero) T;
    const int K = 8;
    const char* xb = reinterpret_cast<const char*>(x.data);
    const long long xs0 = x.strides[0];
    const long long xs1 = x.strides[1];
    const char* tb = reinterpret_cast<const char*>(table.data);
    const long long ts0 = table.strides[0];
    const long long ts1 = table.strides[1];
    const T rf = T(res);
    const int r1 = res + 1;
    const unsigned int mask = (unsigned int)(table_size - 1);
    const int base = l * table_size;
    auto corner_weight = [](int c, T fx, T fy, T fz) __attribute__((always_inline)) -> T {
        const T wx = (c & 1) ? fx : T(1) - fx;
        const T wy = ((c >> 1) & 1) ? fy : T(1) - fy;
        const T wz = ((c >> 2) & 1) ? fz : T(1) - fz;
        const T wxy = wx * wy;
        return wxy * wz;
    };
