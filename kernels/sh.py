"""Real spherical harmonics of degree <= 3 and their derivatives, as Warp functions.

The real SH basis of Sloan ("Stupid Spherical Harmonics (SH) Tricks", GDC 2008), in the form
Plenoxels (Fridovich-Keil et al. 2022) and 3D Gaussian splatting (Kerbl et al. 2023) evaluate it
for a unit direction d = (x, y, z), with their signs, K = (L + 1)^2 functions for degree L:

    l = 0:  Y_0 = C0
    l = 1:  Y_1 = -C1 y,  Y_2 = C1 z,  Y_3 = -C1 x
    l = 2:  Y_4 = C2_0 x y,  Y_5 = C2_1 y z,  Y_6 = C2_2 (2 z^2 - x^2 - y^2),
            Y_7 = C2_3 x z,  Y_8 = C2_4 (x^2 - y^2)
    l = 3:  Y_9 = C3_0 y (3 x^2 - y^2),  Y_10 = C3_1 x y z,  Y_11 = C3_2 y (4 z^2 - x^2 - y^2),
            Y_12 = C3_3 z (2 z^2 - 3 x^2 - 3 y^2),  Y_13 = C3_4 x (4 z^2 - x^2 - y^2),
            Y_14 = C3_5 z (x^2 - y^2),  Y_15 = C3_6 x (x^2 - 3 y^2)

with C0 = 1 / (2 sqrt(pi)), C1 = sqrt(3 / (4 pi)) and the constants below. The functions are
orthonormal on the unit sphere. A colour channel is c(d) = sum_k f_k Y_k(d) for coefficients f.

The polynomials are written in x, y, z without using |d| = 1, so their partial derivatives
dY_k/dx, dY_k/dy, dY_k/dz (`sh_basis_grad`) are those of the polynomials; a caller
whose d = v / |v| is a normalised vector projects the gradient with (I - d d^T) / |v|.

Every function is generic over float32 and float64 (the type of x); the constants are written
once here and `kernels/reference/sh.py` (the NumPy reference) imports them.
"""

from __future__ import annotations

from typing import Any

import warp as wp

MAX_DEGREE = 3
N_COEFFS = (MAX_DEGREE + 1) ** 2

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2_0 = 1.0925484305920792
SH_C2_1 = -1.0925484305920792
SH_C2_2 = 0.31539156525252005
SH_C2_3 = -1.0925484305920792
SH_C2_4 = 0.5462742152960396
SH_C3_0 = -0.5900435899266435
SH_C3_1 = 2.890611442640554
SH_C3_2 = -0.4570457994644658
SH_C3_3 = 0.3731763325901154
SH_C3_4 = -0.4570457994644658
SH_C3_5 = 1.445305721320277
SH_C3_6 = -0.5900435899266435

SH_C2 = (SH_C2_0, SH_C2_1, SH_C2_2, SH_C2_3, SH_C2_4)
SH_C3 = (SH_C3_0, SH_C3_1, SH_C3_2, SH_C3_3, SH_C3_4, SH_C3_5, SH_C3_6)


def n_coeffs(degree: int) -> int:
    """(degree + 1)^2, the number of basis functions up to `degree`."""
    return (degree + 1) * (degree + 1)


@wp.func
def _squares(x: Any, y: Any, z: Any):
    """(x^2, y^2, z^2), the squares every polynomial below uses."""
    return x * x, y * y, z * z


@wp.func
def sh_component(j: int, x: Any, y: Any, z: Any):
    """Y_j(x, y, z) for one index 0 <= j < 16 (for loops that need one function at a time).

    The same expressions, in the same order of operations, as `sh_basis`: the two agree bit for bit.
    """
    xx, yy, zz = _squares(x, y, z)
    if j == 0:
        return type(x)(SH_C0)
    if j == 1:
        return -type(x)(SH_C1) * y
    if j == 2:
        return type(x)(SH_C1) * z
    if j == 3:
        return -type(x)(SH_C1) * x
    if j == 4:
        return type(x)(SH_C2_0) * x * y
    if j == 5:
        return type(x)(SH_C2_1) * y * z
    if j == 6:
        return type(x)(SH_C2_2) * (type(x)(2.0) * zz - xx - yy)
    if j == 7:
        return type(x)(SH_C2_3) * x * z
    if j == 8:
        return type(x)(SH_C2_4) * (xx - yy)
    if j == 9:
        return type(x)(SH_C3_0) * y * (type(x)(3.0) * xx - yy)
    if j == 10:
        return type(x)(SH_C3_1) * x * y * z
    if j == 11:
        return type(x)(SH_C3_2) * y * (type(x)(4.0) * zz - xx - yy)
    if j == 12:
        return type(x)(SH_C3_3) * z * (type(x)(2.0) * zz - type(x)(3.0) * xx - type(x)(3.0) * yy)
    if j == 13:
        return type(x)(SH_C3_4) * x * (type(x)(4.0) * zz - xx - yy)
    if j == 14:
        return type(x)(SH_C3_5) * z * (xx - yy)
    return type(x)(SH_C3_6) * x * (xx - type(x)(3.0) * yy)


@wp.func
def sh_basis(x: Any, y: Any, z: Any):
    """The 16 values Y_k(x, y, z) of degree <= 3, as a vector."""
    xx, yy, zz = _squares(x, y, z)
    return wp.vector(
        type(x)(SH_C0),
        -type(x)(SH_C1) * y, type(x)(SH_C1) * z, -type(x)(SH_C1) * x,
        type(x)(SH_C2_0) * x * y, type(x)(SH_C2_1) * y * z, type(x)(SH_C2_2) * (type(x)(2.0) * zz - xx - yy),
        type(x)(SH_C2_3) * x * z, type(x)(SH_C2_4) * (xx - yy),
        type(x)(SH_C3_0) * y * (type(x)(3.0) * xx - yy), type(x)(SH_C3_1) * x * y * z,
        type(x)(SH_C3_2) * y * (type(x)(4.0) * zz - xx - yy),
        type(x)(SH_C3_3) * z * (type(x)(2.0) * zz - type(x)(3.0) * xx - type(x)(3.0) * yy),
        type(x)(SH_C3_4) * x * (type(x)(4.0) * zz - xx - yy), type(x)(SH_C3_5) * z * (xx - yy),
        type(x)(SH_C3_6) * x * (xx - type(x)(3.0) * yy),
        length=16, dtype=type(x))


@wp.func
def sh_basis_grad(x: Any, y: Any, z: Any):
    """(dY_k/dx, dY_k/dy, dY_k/dz) for the 16 functions of `sh_basis`: three vectors."""
    xx, yy, zz = _squares(x, y, z)
    zero = type(x)(0.0)
    dx = wp.vector(
        zero,
        zero, zero, -type(x)(SH_C1),
        type(x)(SH_C2_0) * y,
        zero,
        -type(x)(2.0) * type(x)(SH_C2_2) * x,
        type(x)(SH_C2_3) * z,
        type(x)(2.0) * type(x)(SH_C2_4) * x,
        type(x)(6.0) * type(x)(SH_C3_0) * x * y,
        type(x)(SH_C3_1) * y * z,
        -type(x)(2.0) * type(x)(SH_C3_2) * x * y,
        -type(x)(6.0) * type(x)(SH_C3_3) * x * z,
        type(x)(SH_C3_4) * (type(x)(4.0) * zz - type(x)(3.0) * xx - yy),
        type(x)(2.0) * type(x)(SH_C3_5) * x * z, type(x)(3.0) * type(x)(SH_C3_6) * (xx - yy),
        length=16, dtype=type(x))
    dy = wp.vector(
        zero,
        -type(x)(SH_C1), zero, zero,
        type(x)(SH_C2_0) * x,
        type(x)(SH_C2_1) * z,
        -type(x)(2.0) * type(x)(SH_C2_2) * y,
        zero,
        -type(x)(2.0) * type(x)(SH_C2_4) * y,
        type(x)(3.0) * type(x)(SH_C3_0) * (xx - yy),
        type(x)(SH_C3_1) * x * z,
        type(x)(SH_C3_2) * (type(x)(4.0) * zz - xx - type(x)(3.0) * yy),
        -type(x)(6.0) * type(x)(SH_C3_3) * y * z,
        -type(x)(2.0) * type(x)(SH_C3_4) * x * y,
        -type(x)(2.0) * type(x)(SH_C3_5) * y * z,
        -type(x)(6.0) * type(x)(SH_C3_6) * x * y,
        length=16, dtype=type(x))
    dz = wp.vector(
        zero,
        zero, type(x)(SH_C1), zero,
        zero, type(x)(SH_C2_1) * y, type(x)(4.0) * type(x)(SH_C2_2) * z, type(x)(SH_C2_3) * x, zero,
        zero, type(x)(SH_C3_1) * x * y, type(x)(8.0) * type(x)(SH_C3_2) * y * z,
        type(x)(SH_C3_3) * (type(x)(6.0) * zz - type(x)(3.0) * xx - type(x)(3.0) * yy),
        type(x)(8.0) * type(x)(SH_C3_4) * x * z,
        type(x)(SH_C3_5) * (xx - yy), zero,
        length=16, dtype=type(x))
    return dx, dy, dz
