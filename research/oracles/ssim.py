"""Dr.Jit oracle for SSIM (kernels/ssim.py): the per-pixel map and its VJP.

Written from Wang et al.'s definition as kernels/ssim.py's docstring states it, as a direct 2-D
correlation (121 taps, not drlab's separable passes): for images x, y (H, W, C) and the 11 x 11
window w(a, b) = g(a) g(b), g the normalised Gaussian (sigma 1.5), taps outside the image 0,

    mu_x = sum_{a,b} w(a, b) x(r + a, c + b)      (and mu_y, e_xx = w * x^2, e_yy, e_xy likewise),
    S = (2 mu_x mu_y + C1)(2 (e_xy - mu_x mu_y) + C2)
        / ((mu_x^2 + mu_y^2 + C1)(e_xx - mu_x^2 + e_yy - mu_y^2 + C2)),
    C1 = (0.01 L)^2,  C2 = (0.03 L)^2.

The VJP for a cotangent map G is Dr.Jit's reverse-mode derivative of sum(G S).
"""

from __future__ import annotations

import numpy as np

from research.oracles import backend, check_array

WINDOW = 11
SIGMA = 1.5


def _taps() -> np.ndarray:
    k = np.arange(WINDOW) - WINDOW // 2
    g = np.exp(-(k**2) / (2.0 * SIGMA**2))
    return g / g.sum()


def ssim_oracle(x: np.ndarray, y: np.ndarray, grad_map: np.ndarray, data_range: float = 1.0
                ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """(SSIM map (H, W, C), (dL/dx, dL/dy)) for L = sum(grad_map * map), in x's dtype."""
    check_array("x", x, (None, None, None))
    check_array("y", y, x.shape)
    check_array("grad_map", grad_map, x.shape)
    be = backend(x.dtype)
    dr = be.dr
    H, W, C = x.shape
    n = H * W * C
    xl, yl = be.leaf(x), be.leaf(y)
    idx = be.arange(n)
    ch = idx % C
    col = (idx // C) % W
    row = idx // (C * W)
    g = _taps()
    h = WINDOW // 2
    sources = [xl, yl, xl * xl, yl * yl, xl * yl]
    moments = [dr.zeros(be.Float, n) for _ in sources]
    for a in range(-h, h + 1):
        for b in range(-h, h + 1):
            rr = be.Int(row) + a
            cc = be.Int(col) + b
            ok = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
            src = be.UInt((dr.select(ok, rr, 0) * W + dr.select(ok, cc, 0)) * C) + ch
            wt = be.Float(float(g[a + h] * g[b + h]))
            for m, s in enumerate(sources):
                moments[m] = dr.fma(wt, dr.gather(be.Float, s, src, ok), moments[m])
        dr.eval(*moments)
    mx, my, exx, eyy, exy = moments
    c1 = be.Float((0.01 * data_range) ** 2)
    c2 = be.Float((0.03 * data_range) ** 2)
    a1 = 2.0 * mx * my + c1
    a2 = 2.0 * (exy - mx * my) + c2
    b1 = mx * mx + my * my + c1
    b2 = (exx - mx * mx) + (eyy - my * my) + c2
    s = (a1 * a2) / (b1 * b2)
    dr.eval(s)
    dr.backward(be.dot([s], [grad_map]))
    return be.numpy(s, x.shape), (be.grad(xl, x.shape), be.grad(yl, y.shape))
