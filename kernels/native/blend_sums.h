// The sums of one compositing step on vector lanes of any clang vector width, shared by blend8.h (eight
// ray lanes: kernels/volume/composite_cpu.py, spheres_cpu.py) and rowblend.cpp (16 pixel lanes:
// kernels/splat/rowblend.py): where the mask m is set,
//     C' = C + w c (each channel),  D' = D + w z,
// each product and each sum rounded on its own (contraction off, as in Warp's generated code); elsewhere
// C and D keep their values. The colour and depth may be vectors (a sample a lane) or scalars (one splat
// for all lanes). Needs lanes.h before it.

    auto blend_sums = [&](const auto m, const auto w, const auto c0, const auto c1, const auto c2, const auto z,
                          auto& R, auto& G, auto& B, auto& D) __attribute__((always_inline)) {
#pragma clang fp contract(off)
        const auto wr = w * c0;
        const auto wg = w * c1;
        const auto wb = w * c2;
        const auto wd = w * z;
        R = sel(m, R + wr, R);
        G = sel(m, G + wg, G);
        B = sel(m, B + wb, B);
        D = sel(m, D + wd, D);
    };
