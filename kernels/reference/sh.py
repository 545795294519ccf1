"""NumPy reference of kernels/sh.py: the real SH basis of degree <= 3 and its derivatives.

Y_k(d) for directions d = (x, y, z), with the constants and signs of kernels/sh.py (Sloan's real
SH as Plenoxels and 3D Gaussian splatting use them); the derivatives are those of the polynomials.
"""

from __future__ import annotations

import numpy as np

from kernels.sh import SH_C0, SH_C1, SH_C2, SH_C3


def sh_basis(d: np.ndarray, degree: int | None = 3) -> np.ndarray:
    """Y_k(d) for directions (..., 3) -> (..., (degree + 1)^2); degree None is plain RGB (Y_0 = 1)."""
    d = np.asarray(d)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    if degree is None:
        return np.ones(x.shape + (1,), dtype=d.dtype)
    cols = [np.full_like(x, SH_C0)]
    if degree >= 1:
        cols += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        cols += [SH_C2[0] * x * y, SH_C2[1] * y * z, SH_C2[2] * (2 * z * z - x * x - y * y), SH_C2[3] * x * z,
                 SH_C2[4] * (x * x - y * y)]
    if degree >= 3:
        cols += [SH_C3[0] * y * (3 * x * x - y * y), SH_C3[1] * x * y * z, SH_C3[2] * y * (4 * z * z - x * x - y * y),
                 SH_C3[3] * z * (2 * z * z - 3 * x * x - 3 * y * y), SH_C3[4] * x * (4 * z * z - x * x - y * y),
                 SH_C3[5] * z * (x * x - y * y), SH_C3[6] * x * (x * x - 3 * y * y)]
    return np.stack(cols, axis=-1)


def sh_basis_grad(d: np.ndarray) -> np.ndarray:
    """dY_k/d(x, y, z) of the degree-3 basis: (..., 16, 3), by the product rule written out."""
    d = np.asarray(d)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    o, zero = np.ones_like(x), np.zeros_like(x)
    c2, c3 = SH_C2, SH_C3
    rows = [
        (zero, zero, zero),
        (zero, -SH_C1 * o, zero), (zero, zero, SH_C1 * o), (-SH_C1 * o, zero, zero),
        (c2[0] * y, c2[0] * x, zero), (zero, c2[1] * z, c2[1] * y), (-2 * c2[2] * x, -2 * c2[2] * y, 4 * c2[2] * z),
        (c2[3] * z, zero, c2[3] * x), (2 * c2[4] * x, -2 * c2[4] * y, zero),
        (6 * c3[0] * x * y, c3[0] * (3 * x * x - 3 * y * y), zero),
        (c3[1] * y * z, c3[1] * x * z, c3[1] * x * y),
        (-2 * c3[2] * x * y, c3[2] * (4 * z * z - x * x - 3 * y * y), 8 * c3[2] * y * z),
        (-6 * c3[3] * x * z, -6 * c3[3] * y * z, c3[3] * (6 * z * z - 3 * x * x - 3 * y * y)),
        (c3[4] * (4 * z * z - 3 * x * x - y * y), -2 * c3[4] * x * y, 8 * c3[4] * x * z),
        (2 * c3[5] * x * z, -2 * c3[5] * y * z, c3[5] * (x * x - y * y)),
        (3 * c3[6] * (x * x - y * y), -6 * c3[6] * x * y, zero),
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)
