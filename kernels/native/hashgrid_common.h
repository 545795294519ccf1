// The set-up shared by kernels/volume/hashgrid_cpu.py's encode and scatter (hashgrid_encode.cpp,
// hashgrid_scatter.cpp): the float type T, K = 8 points a step, the strides of x and the table, the
// level's resolution and its rows base = l table_size.

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
