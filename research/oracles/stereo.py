"""Dr.Jit oracles for kernels/stereo: SAD and ZNCC costs, feature correlation and soft-argmin.

Written from kernels/stereo/costs.py's and disparity.py's docstrings. Volumes are (H, W, D) over
the hypotheses d_k = dmin + k; the left pixel (x, y) matches the right pixel (x - d_k, y) and is in
range when 0 <= x - d_k < W.

* SAD: C = 1/|N| sum_N |L(u, v) - R(u - d, v)| over the (2r+1)^2 window N cut to the image and to
  columns with u - d in [0, W); out of range: max - min of all pixel values of both images.
* ZNCC: C = 1 - cov / sqrt((var L + eps)(var R + eps)) over the same N, with the population
  moments written two-pass (means first, then the centred sums); out of range: 2.
* Feature correlation: corr(x, y, k) = <F_L(x, y), F_R(x - d_k, y)> / sqrt(C), 0 out of range.
* Soft-argmin: d = sum_k d_k softmax_k(-C_k / T), the exponentials taken relative to min_k C_k
  (the shift changes nothing mathematically; it is detached, so it carries no gradient).

The costs have no backward in drlab (they are not differentiated), so their oracles return the
volume only; feature correlation and soft-argmin return their VJPs from Dr.Jit's AD.
"""

from __future__ import annotations

import math

import numpy as np

from research.oracles import backend, check_array


def _cells(be, H: int, W: int, D: int, dmin: int):
    idx = be.arange(H * W * D)
    k = idx % D
    x = be.Int((idx // D) % W)
    y = be.Int(idx // (D * W))
    d = be.Int(k) + dmin
    return x, y, d, (x - d >= 0) & (x - d < W)


def _window(be, L, R, H, W, x, y, d, r):
    """[(ok, left value, right value)] for the window taps of every cell."""
    dr = be.dr
    taps = []
    for dv in range(-r, r + 1):
        for du in range(-r, r + 1):
            u, v = x + du, y + dv
            ok = (u >= 0) & (u < W) & (v >= 0) & (v < H) & (u - d >= 0) & (u - d < W)
            li = be.UInt(dr.select(ok, v * W + u, 0))
            ri = be.UInt(dr.select(ok, v * W + u - d, 0))
            taps.append((ok, dr.gather(be.Float, L, li, ok), dr.gather(be.Float, R, ri, ok)))
    return taps


def window_cost_oracle(left: np.ndarray, right: np.ndarray, dmin: int, dmax: int, radius: int, kind: str,
                       eps: float = 1e-5) -> np.ndarray:
    """The SAD (kind 'sad') or ZNCC (kind 'zncc') volume (H, W, dmax - dmin) in left's dtype."""
    check_array("left", left, (None, None))
    check_array("right", right, left.shape)
    if kind not in ("sad", "zncc"):
        raise ValueError(f"kind: expected 'sad' or 'zncc', got {kind!r}")
    if not dmax > dmin:
        raise ValueError(f"dmax: expected > dmin ({dmin}), got {dmax}")
    be = backend(left.dtype)
    dr = be.dr
    H, W = left.shape
    D = dmax - dmin
    L, R = be.const(left), be.const(right)
    x, y, d, in_range = _cells(be, H, W, D, dmin)
    taps = _window(be, L, R, H, W, x, y, d, radius)
    n = dr.zeros(be.Float, H * W * D)
    for ok, _, _ in taps:
        n = n + dr.select(ok, be.Float(1.0), be.Float(0.0))
    if kind == "sad":
        s = dr.zeros(be.Float, H * W * D)
        for _, lv, rv in taps:
            s = s + dr.abs(lv - rv)
        invalid = float(max(left.max(), right.max())) - float(min(left.min(), right.min()))
        out = dr.select(in_range, s / n, be.Float(invalid))
    else:
        ml = dr.zeros(be.Float, H * W * D)
        mr = dr.zeros(be.Float, H * W * D)
        for _, lv, rv in taps:
            ml, mr = ml + lv, mr + rv
        ml, mr = ml / n, mr / n
        dr.eval(ml, mr)
        vl = dr.zeros(be.Float, H * W * D)
        vr = dr.zeros(be.Float, H * W * D)
        cv = dr.zeros(be.Float, H * W * D)
        for ok, lv, rv in taps:
            a = dr.select(ok, lv - ml, 0.0)
            b = dr.select(ok, rv - mr, 0.0)
            vl, vr, cv = vl + a * a, vr + b * b, cv + a * b
        vl, vr, cv = vl / n, vr / n, cv / n
        out = dr.select(in_range, 1.0 - cv / dr.sqrt((vl + eps) * (vr + eps)), be.Float(2.0))
    dr.eval(out)
    return be.numpy(out, (H, W, D))


def feature_correlation_oracle(fl: np.ndarray, fr: np.ndarray, dmin: int, dmax: int, grad: np.ndarray
                               ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """(corr (H, W, D), (dL/dF_L, dL/dF_R)) for features (C, H, W) and L = sum(grad * corr)."""
    check_array("fl", fl, (None, None, None))
    check_array("fr", fr, fl.shape)
    check_array("grad", grad, (fl.shape[1], fl.shape[2], dmax - dmin))
    be = backend(fl.dtype)
    dr = be.dr
    C, H, W = fl.shape
    D = dmax - dmin
    FL, FR = be.leaf(fl), be.leaf(fr)
    x, y, d, ok = _cells(be, H, W, D, dmin)
    li = be.UInt(y * W + x)
    ri = be.UInt(dr.select(ok, y * W + x - d, 0))
    acc = dr.zeros(be.Float, H * W * D)
    for c in range(C):
        acc = dr.fma(dr.gather(be.Float, FL, li + c * H * W), dr.gather(be.Float, FR, ri + c * H * W, ok), acc)
        if c % 16 == 15:
            dr.eval(acc)
    out = acc * (1.0 / math.sqrt(C))
    dr.eval(out)
    dr.backward(be.dot([out], [grad]))
    return be.numpy(out, (H, W, D)), (be.grad(FL, fl.shape), be.grad(FR, fr.shape))


def soft_argmin_oracle(cost: np.ndarray, dmin: int, grad: np.ndarray, temperature: float = 1.0
                       ) -> tuple[np.ndarray, np.ndarray]:
    """(disparity (H, W), dL/dcost (H, W, D)) for L = sum(grad * disparity)."""
    check_array("cost", cost, (None, None, None))
    check_array("grad", grad, cost.shape[:2])
    if not temperature > 0:
        raise ValueError(f"temperature: expected > 0, got {temperature}")
    be = backend(cost.dtype)
    dr = be.dr
    H, W, D = cost.shape
    c = be.leaf(cost)
    p = be.arange(H * W)
    cols = [dr.gather(be.Float, c, p * D + k) for k in range(D)]
    cmin = dr.detach(cols[0])
    for k in range(1, D):
        cmin = dr.minimum(cmin, dr.detach(cols[k]))
    z = dr.zeros(be.Float, H * W)
    num = dr.zeros(be.Float, H * W)
    inv_t = 1.0 / temperature
    for k in range(D):
        e = dr.exp((cmin - cols[k]) * inv_t)
        z, num = z + e, num + e * float(dmin + k)
        if k % 16 == 15:
            dr.eval(z, num)
    disp = num / z
    dr.eval(disp)
    dr.backward(be.dot([disp], [grad]))
    return be.numpy(disp, (H, W)), be.grad(c, cost.shape)
