// transpose8(in, is, out, os): out[j * os][l] = in[l * is][j], an 8 x 8 float32 transpose in registers
// (unpack, shuffle, 128-bit lane swap; values are moved, never computed). kernels/volume/composite_cpu.py
// (composite_forward.cpp, composite_backward.cpp) turns eight rays' rows of eight samples into eight
// steps' lane vectors with it, and the steps' gradient columns back into rows; transpose8_rgb and
// untranspose8_rgb do the same for interleaved RGB rows. Needs the v8f typedef.

    // out[j * os][l] = in[l * is][j]: an 8 x 8 transpose in registers (unpack, shuffle, 128-bit lane swap)
    auto transpose8 = [](const v8f* in, int is, v8f* out, int os) __attribute__((always_inline)) {
        const v8f t0 = __builtin_shufflevector(in[0], in[is], 0, 8, 1, 9, 4, 12, 5, 13);
        const v8f t1 = __builtin_shufflevector(in[0], in[is], 2, 10, 3, 11, 6, 14, 7, 15);
        const v8f t2 = __builtin_shufflevector(in[2 * is], in[3 * is], 0, 8, 1, 9, 4, 12, 5, 13);
        const v8f t3 = __builtin_shufflevector(in[2 * is], in[3 * is], 2, 10, 3, 11, 6, 14, 7, 15);
        const v8f t4 = __builtin_shufflevector(in[4 * is], in[5 * is], 0, 8, 1, 9, 4, 12, 5, 13);
        const v8f t5 = __builtin_shufflevector(in[4 * is], in[5 * is], 2, 10, 3, 11, 6, 14, 7, 15);
        const v8f t6 = __builtin_shufflevector(in[6 * is], in[7 * is], 0, 8, 1, 9, 4, 12, 5, 13);
        const v8f t7 = __builtin_shufflevector(in[6 * is], in[7 * is], 2, 10, 3, 11, 6, 14, 7, 15);
        const v8f u0 = __builtin_shufflevector(t0, t2, 0, 1, 8, 9, 4, 5, 12, 13);
        const v8f u1 = __builtin_shufflevector(t0, t2, 2, 3, 10, 11, 6, 7, 14, 15);
        const v8f u2 = __builtin_shufflevector(t1, t3, 0, 1, 8, 9, 4, 5, 12, 13);
        const v8f u3 = __builtin_shufflevector(t1, t3, 2, 3, 10, 11, 6, 7, 14, 15);
        const v8f u4 = __builtin_shufflevector(t4, t6, 0, 1, 8, 9, 4, 5, 12, 13);
        const v8f u5 = __builtin_shufflevector(t4, t6, 2, 3, 10, 11, 6, 7, 14, 15);
        const v8f u6 = __builtin_shufflevector(t5, t7, 0, 1, 8, 9, 4, 5, 12, 13);
        const v8f u7 = __builtin_shufflevector(t5, t7, 2, 3, 10, 11, 6, 7, 14, 15);
        out[0 * os] = __builtin_shufflevector(u0, u4, 0, 1, 2, 3, 8, 9, 10, 11);
        out[1 * os] = __builtin_shufflevector(u1, u5, 0, 1, 2, 3, 8, 9, 10, 11);
        out[2 * os] = __builtin_shufflevector(u2, u6, 0, 1, 2, 3, 8, 9, 10, 11);
        out[3 * os] = __builtin_shufflevector(u3, u7, 0, 1, 2, 3, 8, 9, 10, 11);
        out[4 * os] = __builtin_shufflevector(u0, u4, 4, 5, 6, 7, 12, 13, 14, 15);
        out[5 * os] = __builtin_shufflevector(u1, u5, 4, 5, 6, 7, 12, 13, 14, 15);
        out[6 * os] = __builtin_shufflevector(u2, u6, 4, 5, 6, 7, 12, 13, 14, 15);
        out[7 * os] = __builtin_shufflevector(u3, u7, 4, 5, 6, 7, 12, 13, 14, 15);
    };
    // The colours: in[3 l .. 3 l + 2] hold lane l's 24 interleaved floats (eight samples' RGB); out[q][l] = lane
    // l's float q (sample j's channel c at q = 3 j + c): three transposes with input stride 3
    auto transpose8_rgb = [&](const v8f* in, v8f* out) __attribute__((always_inline)) {
        transpose8(in, 3, out, 1);
        transpose8(in + 1, 3, out + 8, 1);
        transpose8(in + 2, 3, out + 16, 1);
    };
    // and back: out[3 l .. 3 l + 2] = lane l's 24 floats from the columns in[q][l]
    auto untranspose8_rgb = [&](const v8f* in, v8f* out) __attribute__((always_inline)) {
        transpose8(in, 1, out, 3);
        transpose8(in + 8, 1, out + 1, 3);
        transpose8(in + 16, 1, out + 2, 3);
    };
