"""Dr.Jit oracle for the chamfer distance (kernels/points/chamfer.py): its value and VJP.

Written from the definition in kernels/points/chamfer.py's docstring (PyTorch3D's and Kaolin's), by
brute force over all N x M pairs in Dr.Jit, never calling drlab:

    CD(X, Y) = (1/N) sum_i |x_i - y_a(i)|^2 + (1/M) sum_j |y_j - x_b(j)|^2,
    a(i) = argmin_j |x_i - y_j|^2,   b(j) = argmin_i |x_i - y_j|^2   (the smallest index among equals).

The argmins are found on detached values: the flat pair array d2[i M + j] is reduced by blocks of M
(Dr.Jit's block_reduce, min) for a(i), and the transposed layout for b(j); the index is the smallest
one whose d2 equals the minimum. The loss is then the differentiable sum over the chosen pairs, so
Dr.Jit's reverse-mode AD gives d(g CD)/dx and d(g CD)/dy for a scalar cotangent g (away from ties, the
derivative of the min is the derivative at the argmin).
"""

from __future__ import annotations

import numpy as np

from research.oracles import backend, check_array


def _argmin_blocks(be, d2, block: int):
    """Per block of `block` consecutive entries: the smallest offset whose value is the block's minimum."""
    dr = be.dr
    n_blocks = dr.width(d2) // block
    mins = dr.block_reduce(dr.ReduceOp.Min, d2, block)
    off = be.arange(n_blocks * block) % block
    is_min = d2 == dr.gather(be.Float, mins, be.arange(n_blocks * block) // block)
    cand = dr.select(is_min, off, be.UInt(block))
    return dr.block_reduce(dr.ReduceOp.Min, cand, block)


def chamfer_oracle(x: np.ndarray, y: np.ndarray, grad: float = 1.0
                   ) -> tuple[float, tuple[np.ndarray, np.ndarray]]:
    """(CD(X, Y), (dL/dx (N, 3), dL/dy (M, 3))) for L = grad * CD, in x's dtype."""
    check_array("x", x, (None, 3))
    check_array("y", y, (None, 3))
    if y.dtype != x.dtype:
        raise ValueError(f"y: expected dtype {x.dtype} like x, got {y.dtype}")
    if len(x) == 0 or len(y) == 0:
        raise ValueError("x, y: expected non-empty clouds")
    be = backend(x.dtype)
    dr = be.dr
    n, m = len(x), len(y)
    xl, yl = be.leaf(x), be.leaf(y)

    def coord(v, idx, c):
        return dr.gather(be.Float, v, idx * 3 + c)

    def sq(xi, yj):
        dx, dy, dz = (coord(xl, xi, c) - coord(yl, yj, c) for c in range(3))
        return dx * dx + dy * dy + dz * dz

    with dr.suspend_grad():
        t = be.arange(n * m)
        d2_xy = sq(t // m, t % m)            # pair (i, j) at i M + j: blocks of M per x_i
        d2_yx = sq(t % n, t // n)            # pair (i, j) at j N + i: blocks of N per y_j
        dr.eval(d2_xy, d2_yx)
        a = _argmin_blocks(be, d2_xy, m)
        b = _argmin_blocks(be, d2_yx, n)
        dr.eval(a, b)
    ii, jj = be.arange(n), be.arange(m)
    loss = dr.sum(sq(ii, be.UInt(a))) / n + dr.sum(sq(be.UInt(b), jj)) / m
    dr.eval(loss)
    dr.backward(loss * be.Float(grad))
    value = float(np.array(loss, dtype=np.float64).ravel()[0])
    return value, (be.grad(xl, x.shape), be.grad(yl, y.shape))
