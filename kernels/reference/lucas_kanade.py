"""Plain NumPy reference of kernels.lucas_kanade's forward pass: dense Lucas-Kanade (Lucas and Kanade,
IJCAI 1981) with Shi and Tomasi's validity test (CVPR 1994), pyramidal as in Bouguet (Intel, 2000).

Loops over pixels in float64, written from the definitions in
kernels.lucas_kanade: central-difference gradients (1), one LK step (2) with the
minimum-eigenvalue validity test (3) (solved with np.linalg), the [1, 3, 3, 1] / 8
pyramid and the coarse-to-fine scheme. Borders are replicated throughout.
"""

from __future__ import annotations

import numpy as np


def px(img: np.ndarray, i: int, j: int) -> float:
    """Pixel (i, j) with replicated borders."""
    return img[min(max(i, 0), img.shape[0] - 1), min(max(j, 0), img.shape[1] - 1)]


def gradients(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(1): (Ix, Iy) by central differences."""
    ix, iy = np.zeros_like(img), np.zeros_like(img)
    for i in range(img.shape[0]):
        for j in range(img.shape[1]):
            ix[i, j] = (px(img, i, j + 1) - px(img, i, j - 1)) / 2
            iy[i, j] = (px(img, i + 1, j) - px(img, i - 1, j)) / 2
    return ix, iy


def sample(img: np.ndarray, x: float, y: float) -> float:
    """Bilinear sample at continuous (x, y) (pixel centres at +0.5), borders replicated."""
    u, v = x - 0.5, y - 0.5
    j, i = int(np.floor(u)), int(np.floor(v))
    ax, ay = u - j, v - i
    return ((1 - ay) * ((1 - ax) * px(img, i, j) + ax * px(img, i, j + 1))
            + ay * ((1 - ax) * px(img, i + 1, j) + ax * px(img, i + 1, j + 1)))


def lk_step(img1: np.ndarray, img2: np.ndarray, flow_in: np.ndarray, half_window: int,
            min_eigenvalue: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One step of (2) at every pixel with the validity test (3): (flow, valid, lambda_min)."""
    h, w = img1.shape
    ix, iy = gradients(img1)
    out, lam_out, valid = flow_in.copy(), np.zeros((h, w)), np.zeros((h, w), bool)
    for i in range(h):
        for j in range(w):
            G, b, n = np.zeros((2, 2)), np.zeros(2), 0
            for qi in range(max(0, i - half_window), min(h, i + half_window + 1)):
                for qj in range(max(0, j - half_window), min(w, j + half_window + 1)):
                    g = np.array([ix[qi, qj], iy[qi, qj]])
                    e = sample(img2, qj + 0.5 + flow_in[i, j, 0], qi + 0.5 + flow_in[i, j, 1]) - img1[qi, qj]
                    G += np.outer(g, g)
                    b += e * g
                    n += 1
            lam = np.linalg.eigvalsh(G / n)[0]
            lam_out[i, j] = lam
            if lam >= min_eigenvalue:
                out[i, j] += np.linalg.solve(G, -b)
                valid[i, j] = True
    return out, valid, lam_out


def downsample(img: np.ndarray) -> np.ndarray:
    """One pyramid level: [1, 3, 3, 1] / 8 in both directions, centred between pixels 2k and 2k + 1."""
    k = np.array([1.0, 3.0, 3.0, 1.0]) / 8
    out = np.zeros((img.shape[0] // 2, img.shape[1] // 2))
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            out[i, j] = sum(k[a] * k[b] * px(img, 2 * i - 1 + a, 2 * j - 1 + b) for a in range(4) for b in range(4))
    return out


def upsample_flow(coarse: np.ndarray, height: int, width: int) -> np.ndarray:
    """Coarse flow (h, w, 2) sampled at ((j + 0.5) / 2, (i + 0.5) / 2) and doubled: (height, width, 2)."""
    out = np.zeros((height, width, 2))
    for i in range(height):
        for j in range(width):
            for k in range(2):
                out[i, j, k] = 2 * sample(coarse[..., k], (j + 0.5) / 2, (i + 0.5) / 2)
    return out


def pyramidal(img1: np.ndarray, img2: np.ndarray, levels: int, half_window: int, iterations: int,
              min_eigenvalue: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Coarse-to-fine LK: (flow, valid, lambda_min) of the finest level."""
    pyr1, pyr2 = [img1], [img2]
    for _ in range(1, levels):
        pyr1.append(downsample(pyr1[-1]))
        pyr2.append(downsample(pyr2[-1]))
    fl = np.zeros((*pyr1[-1].shape, 2))
    for lvl in range(levels - 1, -1, -1):
        if lvl < levels - 1:
            fl = upsample_flow(fl, *pyr1[lvl].shape)
        for _ in range(iterations):
            fl, valid, lam = lk_step(pyr1[lvl], pyr2[lvl], fl, half_window, min_eigenvalue)
    return fl, valid, lam
