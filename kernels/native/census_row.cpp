// kernels/stereo/census.py, _census_row: the census transform of image row y (float32), bit
// n - 1 - i set where neighbour i (raster order, centre skipped) is darker than the centre; where the
// window lies inside the image 16 pixels at once (one unaligned row load per neighbour), elsewhere pixel
// by pixel with clamped coordinates. Comparisons and bit operations only, so census_kernel's strings
// exactly. Returns 0 (does nothing) on CUDA.

#if defined(__CUDA_ARCH__)
    return 0;
#else
    typedef float v16f __attribute__((ext_vector_type(16)));
    typedef int v16i __attribute__((ext_vector_type(16)));
    typedef unsigned long long v16u __attribute__((ext_vector_type(16)));
    const int H = img.shape[0];
    const int W = img.shape[1];
    const int n = (2 * ry + 1) * (2 * rx + 1) - 1;
    const bool rows_in = y >= ry && y < H - ry && img.strides[1] == (int)sizeof(float);
    int x = 0;
    while (x < W) {
        if (rows_in && x >= rx && x + 16 <= W - rx) {
            v16f c;
            __builtin_memcpy(&c, &wp::index(img, y, x), 64);
            v16u bits = 0;
            int i = 0;
            for (int dy = -ry; dy <= ry; ++dy) {
                const float* rowp = &wp::index(img, y + dy, x);
                for (int dx = -rx; dx <= rx; ++dx) {
                    if (dy == 0 && dx == 0)
                        continue;
                    v16f q;
                    __builtin_memcpy(&q, rowp + dx, 64);
                    const v16i lt = q < c;
                    const v16u bit = __builtin_convertvector(lt & 1, v16u);
                    bits = bits | (bit << (unsigned long long)(n - 1 - i));
                    ++i;
                }
            }
            for (int l = 0; l < 16; ++l)
                wp::index(out, y, x + l) = bits[l];
            x += 16;
        } else {
            const float c = wp::index(img, y, x);
            unsigned long long bits = 0;
            for (int dy = -ry; dy <= ry; ++dy) {
                const int yy = y + dy < 0 ? 0 : (y + dy > H - 1 ? H - 1 : y + dy);
                for (int dx = -rx; dx <= rx; ++dx) {
                    if (dy == 0 && dx == 0)
                        continue;
                    const int xx = x + dx < 0 ? 0 : (x + dx > W - 1 ? W - 1 : x + dx);
                    const float q = wp::index(img, yy, xx);
                    bits = (bits << 1) | (unsigned long long)(q < c ? 1 : 0);
                }
            }
            wp::index(out, y, x) = bits;
            x += 1;
        }
    }
    return 0;
#endif
