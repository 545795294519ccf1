// The lane helper shared by the clang-vector fast paths (kernels/volume/composite_cpu.py,
// kernels/volume/spheres_cpu.py, kernels/splat/rowblend.py): sel(m, a, b) is, lane by lane, a where the
// integer mask m (lanes all ones or all zeros, as a vector comparison gives them) is set, else b, chosen
// by the bits (no arithmetic, so no rounding and -0 / NaN payloads kept); a and b of one clang vector
// type, m the integer vector type of its width. Include it before the first use.

    auto sel = [](auto m, auto a, auto b) __attribute__((always_inline)) {
        typedef decltype(m) I;
        typedef decltype(a) F;
        return __builtin_bit_cast(F, (m & __builtin_bit_cast(I, a)) | (~m & __builtin_bit_cast(I, b)));
    };
