"""A float32 exp on 16 SIMD lanes with the bits of NumPy's float32 exp (its AVX2/AVX-512 loop): the C++ in
kernels/native/npexp16.h (clang vector extensions), included by the wp.func_native kernels of
kernels.volume.composite_cpu, whose factors exp(-sigma delta) must be those NumPy's pass computed before
(kernels.volume.composite._fill_factor), and kernels.volume.spheres_cpu; this module checks it against np.exp.

NumPy (x86-64 builds whose float32 exp dispatches to the AVX2+FMA3 or AVX512F loop of
loops_exponent_log.dispatch; 2.4.6 here) evaluates exp(x) lane by lane as:

    NaN -> 0 (remembered);  x >= XMAX = 88.72283935546875 -> +inf;  x <= XMIN = -103.97208404541015625 -> 0
    (those lanes evaluate the rest with x = 0 and are replaced at the end)
    q = rint(x * LOG2E)                        the product rounded to float32, then rounded to an integer by
                                               adding and subtracting 1.5 * 2^23
    y = fma(q, C1, x);  y = fma(q, C2, y)      Cody-Waite: C1 + C2 ~ -ln 2 (C1 with trailing zero bits)
    P = fma(fma(fma(fma(fma(P5, y, P4), y, P3), y, P2), y, P1), y, P0)
    Q = fma(fma(Q2, y, Q1), y, Q0)             a 5/2 rational minimax approximation of e^y
    exp(x) ~ (P / Q) 2^q                       IEEE division, then 2^q applied with ONE rounding
                                               (AVX-512's vscalefps; AVX2's exponent add, with a division by a
                                               power of two where the result is subnormal: the same bits)

(the literal constants in npexp16.h are the float32 values of NumPy's NPY_COEFF_*_EXPf, NPY_CODY_WAITE_LOGE_2_*f and
NPY_LOG2Ef; a third Cody-Waite step with constant 0 changes no bit and is left out). Here 2^q is applied as two
exact power-of-two products (p 2^h) 2^(q-h), h = floor(q/2): p 2^h is a normal float (q >= -150), so the second
product is the only rounding, the correctly rounded p 2^q that vscalefps gives.

The bits equal np.exp's for all 2^32 float32 inputs on this machine (NumPy 2.4.6, AVX-512 loop; checked once with
`mismatches` over every input, tests sweep a sample with every edge). NumPy builds or CPUs that run another loop
(no AVX2/FMA: the C library's expf; other architectures) give other bits for some inputs: callers check a fixed set
against np.exp at first use (`numpy_agrees`) and keep NumPy's pass when anything differs.

npexp16.h sets `ne` (v16f) to exp(`nx`) lane by lane; a snippet includes npexp_types.h (the v16f and v16i types)
before it.
Compile with floating-point contraction off (`#pragma clang fp contract(off)`): each product, sum and the rounding
trick must round on its own.
"""

import numpy as np
import warp as wp

from kernels.native import built_once, source

_kernels: dict = {}


def _exp_kernel():
    """The kernel that applies npexp16.h to a float32 array, 16 values a thread; built once."""
    return built_once(_kernels, "npexp16_array", _build_exp_kernel)


def _build_exp_kernel():
    f32 = wp.array(dtype=wp.float32)

    def npexp16_block(x: f32, y: f32, b: int): ...

    native = wp.func_native(source("npexp_array.cpp"))(npexp16_block)

    @wp.kernel(module="unique", module_options={"enable_backward": False})
    def npexp16_array(x: f32, y: f32):
        native(x, y, wp.tid())

    return npexp16_array


def exp(x: np.ndarray) -> np.ndarray:
    """npexp16.h over a float32 array on the CPU (for the check and the tests): a new float32 array."""
    xs = np.ascontiguousarray(x, dtype=np.float32).ravel()
    out = np.empty_like(xs)
    if xs.size:
        wx = wp.array(xs, dtype=wp.float32, device="cpu", copy=False)
        wy = wp.array(out, dtype=wp.float32, device="cpu", copy=False)
        wp.launch(_exp_kernel(), dim=(xs.size + 15) // 16, inputs=[wx, wy], device="cpu")
    return out.reshape(np.shape(x))


def mismatches(lo: int, hi: int) -> int:
    """How many float32 bit patterns b in [lo, hi) give other bits from npexp16.h than from np.exp."""
    x = np.arange(lo, hi, dtype=np.uint64).astype(np.uint32).view(np.float32)
    with np.errstate(all="ignore"):
        want = np.exp(x)
    return int(np.count_nonzero(exp(x).view(np.uint32) != want.view(np.uint32)))


def check_set() -> np.ndarray:
    """A fixed set of float32 inputs that covers every exponent of both signs and the edges: for each of the 512
    sign-and-exponent prefixes, 512 mantissas (the extremes and a fixed pseudo-random spread); the neighbours of
    XMAX and XMIN and of the points where rint(x log2 e) changes the scale into the subnormal results; 0, -0, inf,
    -inf and NaNs of both signs with payloads (262,000 values or so)."""
    rng = np.random.default_rng(20260)
    mant = np.concatenate([np.array([0, 1, 2, 0x3FFFFF, 0x400000, 0x7FFFFE, 0x7FFFFF], np.uint32),
                           rng.integers(0, 1 << 23, 505, dtype=np.uint32)])
    prefix = np.arange(512, dtype=np.uint32) << np.uint32(23)
    grid = (prefix[:, None] | mant[None, :]).ravel()
    edges = []
    for v in (88.72283935546875, -103.97208404541015625, -87.33654, -88.0, -100.0, -103.0, 88.0, 0.34657359):
        c = int(np.float32(v).view(np.uint32))
        edges.append(np.arange(c - 2048, c + 2048, dtype=np.int64).astype(np.uint32))
    # x where x log2 e crosses k + 1/2 for k = -150 .. 128 (the scale steps), a few neighbours each
    k = np.arange(-150, 129, dtype=np.float64)
    mid = ((k + 0.5) / np.log2(np.e)).astype(np.float32).view(np.uint32).astype(np.int64)
    edges.append((mid[:, None] + np.arange(-8, 9)[None, :]).ravel().astype(np.uint32))
    special = np.array([0, 0x80000000, 0x7F800000, 0xFF800000, 0x7FC00000, 0xFFC00000, 0x7F800001, 0xFFBFFFFF,
                        0x7FFFFFFF, 0xFFFFFFFF], np.uint32)
    return np.concatenate([grid, *edges, special]).view(np.float32)


_agrees: bool | None = None


def numpy_agrees() -> bool:
    """True when npexp16.h gives np.exp's bits on `check_set()` in this process (NumPy and CPU); computed once."""
    global _agrees
    if _agrees is None:
        x = check_set()
        with np.errstate(all="ignore"):
            want = np.exp(x)
        _agrees = bool(np.array_equal(exp(x).view(np.uint32), want.view(np.uint32)))
    return _agrees
