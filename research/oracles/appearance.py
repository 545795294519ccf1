"""Dr.Jit oracle for the bilateral-grid slice (kernels/appearance.py): the sliced image and its VJPs.

Written from the equations of kernels/appearance.py's docstring (Wang et al. 2024, as gsplat's
bilateral grid), one pixel per lane. For a grid G (L, GH, GW, 12) and an image p (H, W, 3), pixel
(i, j) is looked up at

    x = (j + 1/2) / W (GW - 1),   y = (i + 1/2) / H (GH - 1),   z = clamp(lum(p), 0, 1) (L - 1),
    lum(p) = 0.299 r + 0.587 g + 0.114 b,

each coordinate clamped to [0, n - 1] with the lower node t0 = min(floor(t), n - 2) (>= 0), the
upper t1 = min(t0 + 1, n - 1) and f = t - t0; the 8 corners' trilinear weights give the 3x4
transform A = sum_n w_n G[n], and out_c = sum_{k<3} A_{4c+k} p_k + A_{4c+3}.

The VJPs for a cotangent image g are Dr.Jit's reverse-mode derivatives of sum(g out) with respect
to G and p (the floor and the node choice are constants of the pixel, as in drlab's adjoint).
"""

from __future__ import annotations

import numpy as np

from research.oracles import backend, check_array

ENTRIES = 12
LUMA = (0.299, 0.587, 0.114)


def _axis(be, t, n: int):
    """(t0, t1, f) on one axis of n nodes, t a Dr.Jit Float (module docstring)."""
    dr = be.dr
    tc = dr.clip(t, 0.0, float(n - 1))
    t0 = dr.maximum(dr.minimum(be.Int(dr.floor(dr.detach(tc))), n - 2), 0)
    t1 = dr.minimum(t0 + 1, n - 1)
    return t0, t1, tc - be.Float(t0)


def bilateral_slice_oracle(grid: np.ndarray, rgb: np.ndarray, grad_out: np.ndarray
                           ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(out (H, W, 3), {"grid": dL/dgrid, "rgb": dL/drgb}) for L = sum(grad_out * out), in rgb's dtype."""
    check_array("grid", grid, (None, None, None, ENTRIES))
    check_array("rgb", rgb, (None, None, 3))
    check_array("grad_out", grad_out, rgb.shape)
    be = backend(rgb.dtype)
    dr = be.dr
    gl, gh, gw = (int(s) for s in grid.shape[:3])
    h, w = int(rgb.shape[0]), int(rgb.shape[1])
    G, P = be.leaf(grid), be.leaf(rgb)
    pix = be.arange(h * w)
    row, col = be.Float(pix // w), be.Float(pix % w)
    p = [dr.gather(be.Float, P, pix * 3 + k) for k in range(3)]
    lum = LUMA[0] * p[0] + LUMA[1] * p[1] + LUMA[2] * p[2]
    axes = (_axis(be, dr.clip(lum, 0.0, 1.0) * float(gl - 1), gl),  # z, the slowest grid axis
            _axis(be, (row + 0.5) / float(h) * float(gh - 1), gh),
            _axis(be, (col + 0.5) / float(w) * float(gw - 1), gw))
    transform = [dr.zeros(be.Float, h * w) for _ in range(ENTRIES)]
    for corner in range(8):
        weight = be.Float(1.0)
        node = be.Int(0)
        for axis, ((t0, t1, f), n) in enumerate(zip(axes, (gl, gh, gw))):
            upper = (corner >> (2 - axis)) & 1
            weight = weight * (f if upper else 1.0 - f)
            node = node * n + (t1 if upper else t0)
        base = be.UInt(node) * ENTRIES
        for e in range(ENTRIES):
            transform[e] = dr.fma(weight, dr.gather(be.Float, G, base + e), transform[e])
    out = []
    for c in range(3):
        a = transform[4 * c: 4 * c + 4]
        out.append(a[0] * p[0] + a[1] * p[1] + a[2] * p[2] + a[3])
    dr.eval(*out)
    dr.backward(be.dot(out, [np.ascontiguousarray(grad_out[..., c]) for c in range(3)]))
    values = np.stack([be.numpy(o, (h, w)) for o in out], axis=-1)
    return values, {"grid": be.grad(G, grid.shape), "rgb": be.grad(P, rgb.shape)}
