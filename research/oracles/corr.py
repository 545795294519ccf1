"""Dr.Jit oracle for kernels/corr: RAFT's all-pairs volume, its pyramid and the windowed lookup.

Written from kernels/corr/__init__.py's equations, by their definitions (the volume is formed in
full and pooled; drlab's on-the-fly path, which pools the features instead, is compared against
the same oracle). For features f1, f2 (C, H, W), N = H W, and coordinates (2, H, W) (x right, y
down, pixel centres at +0.5):

    V^0[p, q] = sum_c f1[c, p] f2[c, q] / sqrt(C)                                     (1)
    V^l[p, h', w'] = 1/4 sum_{a, b in {0, 1}} V^{l-1}[p, 2h' + a, 2w' + b]             (2)
    S(x, y) = bilinear with u = x - 1/2, v = y - 1/2, taps outside the level 0        (3)
    out[l (2r+1)^2 + a (2r+1) + b, p] = V^l[p](x_p / 2^l + a - r, y_p / 2^l + b - r)  (4)

The VJPs (f1, f2, coords) are Dr.Jit's reverse-mode derivatives of sum(G out); the floor in (3)
has derivative 0, so the coordinate gradient is that of the bilinear piece the point lies on.
"""

from __future__ import annotations

import math

import numpy as np

from research.oracles import backend, check_array


def _level_shapes(H: int, W: int, levels: int) -> list[tuple[int, int]]:
    return [(H >> l, W >> l) for l in range(levels)]


def lookup_oracle(f1: np.ndarray, f2: np.ndarray, coords: np.ndarray, levels: int, radius: int,
                  grad: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(lookup output (L (2r+1)^2, H, W), {"f1", "f2", "coords": VJPs}) for L = sum(grad * out)."""
    check_array("f1", f1, (None, None, None))
    check_array("f2", f2, f1.shape)
    check_array("coords", coords, (2, f1.shape[1], f1.shape[2]))
    if not (isinstance(levels, int) and levels >= 1 and f1.shape[1] >> (levels - 1) >= 1
            and f1.shape[2] >> (levels - 1) >= 1):
        raise ValueError(f"levels: expected 1 to the number of 2x2 poolings frame 2 allows, got {levels!r}")
    if not (isinstance(radius, int) and radius >= 0):
        raise ValueError(f"radius: expected an integer >= 0, got {radius!r}")
    check_array("grad", grad, (levels * (2 * radius + 1) ** 2, f1.shape[1], f1.shape[2]))
    be = backend(f1.dtype)
    dr = be.dr
    C, H, W = f1.shape
    N = H * W
    F1, F2, XY = be.leaf(f1), be.leaf(f2), be.leaf(coords)
    # (1): the volume, flat [p N + q].
    idx = be.arange(N * N)
    p, q = idx // N, idx % N
    vol = dr.zeros(be.Float, N * N)
    for c in range(C):
        vol = dr.fma(dr.gather(be.Float, F1, p + c * N), dr.gather(be.Float, F2, q + c * N), vol)
        if c % 16 == 15:
            dr.eval(vol)
    vol = vol * (1.0 / math.sqrt(C))
    dr.eval(vol)
    # (2): the pyramid, level l flat [p Hl Wl + h' Wl + w'].
    shapes = _level_shapes(H, W, levels)
    pyr = [vol]
    for l in range(1, levels):
        (hp, wp_), (hl, wl) = shapes[l - 1], shapes[l]
        i = be.arange(N * hl * wl)
        pp, rest = i // (hl * wl), i % (hl * wl)
        hh, ww = rest // wl, rest % wl
        acc = dr.zeros(be.Float, N * hl * wl)
        for a in (0, 1):
            for b in (0, 1):
                acc = acc + dr.gather(be.Float, pyr[-1], pp * (hp * wp_) + (2 * hh + a) * wp_ + 2 * ww + b)
        pyr.append(acc * 0.25)
        dr.eval(pyr[-1])
    # (3)-(4): per level, every (a, b, p) at once; output flat [channel N + p].
    side = 2 * radius + 1
    outs = []
    for l, (hl, wl) in enumerate(shapes):
        i = be.arange(side * side * N)
        ab, pix = i // N, i % N
        a, b = be.Int(ab // side), be.Int(ab % side)
        x = dr.gather(be.Float, XY, pix) * (0.5 ** l) + be.Float(a - radius)
        y = dr.gather(be.Float, XY, pix + N) * (0.5 ** l) + be.Float(b - radius)
        u, v = x - 0.5, y - 0.5
        iu, jv = dr.floor(u), dr.floor(v)
        fx, fy = u - iu, v - jv
        i0, j0 = be.Int(dr.detach(iu)), be.Int(dr.detach(jv))
        val = dr.zeros(be.Float, side * side * N)
        for dj, wy in ((0, 1.0 - fy), (1, fy)):
            for di, wx in ((0, 1.0 - fx), (1, fx)):
                col, row = i0 + di, j0 + dj
                ok = (col >= 0) & (col < wl) & (row >= 0) & (row < hl)
                src = be.UInt(dr.select(ok, row * wl + col, 0)) + pix * (hl * wl)
                val = val + wx * wy * dr.gather(be.Float, pyr[l], src, ok)
        dr.eval(val)
        outs.append(val)
    loss = be.Float(0.0)
    g = np.asarray(grad).reshape(levels, side * side * N)
    for l in range(levels):
        loss = loss + dr.sum(outs[l] * be.const(g[l]))
    dr.backward(loss)
    out = np.concatenate([be.numpy(o, (side * side, H, W)) for o in outs], axis=0)
    return out, {"f1": be.grad(F1, f1.shape), "f2": be.grad(F2, f2.shape), "coords": be.grad(XY, coords.shape)}
