"""Plain NumPy reference of kernels.corr's forward pass: the correlation volume, pyramid and lookup of
RAFT (Teed and Deng, "RAFT: Recurrent All-Pairs Field Transforms for Optical Flow", ECCV 2020).

Loops over pixels in float64, written from the definitions in kernels.corr:
the volume (1), 2x2 pooling (2), bilinear sampling with zeros outside (3) and
the windowed lookup (4) in RAFT's channel order. The on-the-fly lookup has the
same reference as the dense one (it computes the same output), and the pooled
feature pyramid is `pyramid` applied to f2.
"""

from __future__ import annotations

import numpy as np


def volume(f1: np.ndarray, f2: np.ndarray) -> np.ndarray:
    """(1): V[y1, x1, y2, x2] = f1[:, y1, x1] . f2[:, y2, x2] / sqrt(C), shape (H, W, H, W)."""
    c, h, w = f1.shape
    out = np.zeros((h, w, h, w))
    for y1 in range(h):
        for x1 in range(w):
            for y2 in range(h):
                for x2 in range(w):
                    out[y1, x1, y2, x2] = np.dot(f1[:, y1, x1], f2[:, y2, x2]) / np.sqrt(c)
    return out


def pool(x: np.ndarray) -> np.ndarray:
    """(2): 2x2 average over the last two axes, dropping an odd last row/column."""
    h, w = x.shape[-2] // 2, x.shape[-1] // 2
    out = np.zeros(x.shape[:-2] + (h, w))
    for y in range(h):
        for xx in range(w):
            out[..., y, xx] = x[..., 2 * y:2 * y + 2, 2 * xx:2 * xx + 2].mean(axis=(-2, -1))
    return out


def pyramid(x: np.ndarray, levels: int) -> list[np.ndarray]:
    """[x, pool(x), pool(pool(x)), ...]: the volume pyramid of a volume, the feature pyramid of f2."""
    out = [x]
    for _ in range(1, levels):
        out.append(pool(out[-1]))
    return out


def bilinear(img: np.ndarray, x: float, y: float) -> float:
    """(3): sample img (H, W) at continuous (x, y), pixel centres at +0.5, each tap 0 outside."""
    h, w = img.shape
    u, v = x - 0.5, y - 0.5
    i, j = int(np.floor(u)), int(np.floor(v))
    fx, fy = u - i, v - j

    def tap(r: int, c: int) -> float:
        return img[r, c] if 0 <= r < h and 0 <= c < w else 0.0

    return ((1 - fx) * (1 - fy) * tap(j, i) + fx * (1 - fy) * tap(j, i + 1)
            + (1 - fx) * fy * tap(j + 1, i) + fx * fy * tap(j + 1, i + 1))


def lookup(levels: list[np.ndarray], coords: np.ndarray, radius: int) -> np.ndarray:
    """(4), as RAFT's CorrBlock.__call__: per level, delta = stack(meshgrid(dy, dx)) is ADDED to (x, y),
    so the first (slow) window index moves x and the second moves y. Shape (L (2r+1)^2, H, W)."""
    side = 2 * radius + 1
    h, w = coords.shape[1:]
    out = np.zeros((len(levels) * side * side, h, w))
    for lvl, level in enumerate(levels):
        for y1 in range(h):
            for x1 in range(w):
                cx, cy = coords[0, y1, x1] / 2 ** lvl, coords[1, y1, x1] / 2 ** lvl
                for a in range(side):
                    for b in range(side):
                        out[lvl * side * side + a * side + b, y1, x1] = bilinear(
                            level[y1, x1], cx + a - radius, cy + b - radius)
    return out
