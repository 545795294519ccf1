// kernels/corr/patch_cpu.py, onthefly_group_pixels: the counting sort of a level's pixels by their window
// origin (i0, j0), both clamped to [-SIDE, width] and [-SIDE, height]: order, the sorted j0 and each
// column group's first position, for patch_groups.cpp. Plain C++. Template parameter SIDE = 2r + 2.

    const int side = @SIDE@;
    const int n = i0s.shape[0];
    const int height = height_l;
    const int width = width_l;
    const int n_rows = height + side + 1;  // j0 clamped to [-side, height]
    const int n_buckets = width + side + 1;  // i0 clamped to [-side, width]
    const int* i0 = reinterpret_cast<const int*>(i0s.data);
    const int* j0 = reinterpret_cast<const int*>(j0s.data);
    int* ord = reinterpret_cast<int*>(order.data);
    int* sj0 = reinterpret_cast<int*>(sorted_j0.data);
    int* st = reinterpret_cast<int*>(starts.data);
    int* count = reinterpret_cast<int*>(counts.data);
    auto clamp = [](int v, int lo, int hi) { return v < lo ? lo : (v > hi ? hi : v); };
    auto key = [&](int p) {
        return (clamp(i0[p], -side, width) + side) * n_rows + clamp(j0[p], -side, height) + side;
    };
    for (int k = 0; k <= n_buckets * n_rows; ++k)
        count[k] = 0;
    for (int p = 0; p < n; ++p)
        ++count[key(p) + 1];
    for (int k = 0; k < n_buckets * n_rows; ++k)
        count[k + 1] += count[k];
    for (int b = 0; b < n_buckets; ++b)
        st[b] = count[b * n_rows];
    st[n_buckets] = n;
    for (int p = 0; p < n; ++p) {
        const int k = key(p);
        const int at = count[k]++;
        ord[at] = p;
        sj0[at] = clamp(j0[p], -side, height);
    }
