// One front-to-back compositing step on eight ray lanes, for kernels/volume/composite_cpu.py's forward
// (composite_forward.cpp) and kernels/volume/spheres_cpu.py's pass 3 (spheres_pass3.h): where `run`,
//     w = T (1 - e),  T' = T e,  C' = C + w c (each channel),  D' = D + w z,
// each product and each sum rounded on its own (contraction off, as in Warp's generated code);
// elsewhere T, C and D keep their values (the sums: blend_sums.h). Needs the v8f / v8i typedefs, lanes.h
// and blend_sums.h before it.

    auto blend8 = [&](const v8i run, const v8f e, const v8f c0, const v8f c1, const v8f c2, const v8f zk, v8f& T,
                     v8f& R, v8f& G, v8f& B, v8f& D) __attribute__((always_inline)) {
#pragma clang fp contract(off)
        const v8f om = (v8f)1.0f - e;
        const v8f w = T * om;
        const v8f Tn = T * e;
        blend_sums(run, w, c0, c1, c2, zk, R, G, B, D);
        T = sel(run, Tn, T);
    };
